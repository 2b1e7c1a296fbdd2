"""Forward-model and sampler settings of a fit, with their defaults written once.

:class:`FitSettings` holds what :func:`bayesbeam.inference.fit.fit` takes besides the
trial, model, priors and seed: the mesh, the initial condition and the emcee budget.
:data:`FIT_DEFAULTS` is the package default (a full fit), and every entry point reads
its defaults from it: the keywords of ``fit``, the model comparison
(:func:`bayesbeam.comparison.scoring.evaluate` and
:func:`bayesbeam.comparison.compare.compare`, through :func:`fit_settings`), the task
settings of :mod:`bayesbeam.jobs.tasks` and the options of ``bayesbeam fit`` and
``bayesbeam compare``. :data:`DIAGNOSIS_DEFAULTS` is the shorter per-model budget of
:func:`bayesbeam.diagnosis.diagnose.diagnose` and ``bayesbeam diagnose``; the demo's
budgets are overrides in :mod:`bayesbeam.jobs.demo`.

The constants of the stopping rule (``n_tau``, ``tau_rtol``, ``check_every``,
``burn_in_taus``, ``thin``) are the defaults of :func:`bayesbeam.stats.sampling.run_emcee`;
``fit`` changes them only through its ``sampler_options``.

Standard library only: the command line builds its parsers, whose help shows these
defaults, without importing numpy.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

__all__ = [
    "COSTLY_ELEMENTS",
    "DIAGNOSIS_DEFAULTS",
    "DIAGNOSIS_STOPPING",
    "FIT_DEFAULTS",
    "FitSettings",
    "MAX_ELEMENTS",
    "fit_settings",
    "mesh_cost",
    "mesh_cost_text",
    "walker_count",
]


@dataclass(frozen=True)
class FitSettings:
    """Forward-model and sampler settings of one fit; the field defaults are the package's.

    Attributes
    ----------
    n_elements : int
        Hermite beam elements of the forward model: the starting (coarsest) mesh.
    refine_mesh : bool
        Refine the mesh until the MAP's prediction converges
        (:func:`bayesbeam.inference.mesh.converge_mesh`); False keeps ``n_elements`` and
        only reports the check.
    initial : str
        Initial-condition kind: ``'release'``, ``'impulse'`` or ``'modes:K'`` (see
        :class:`bayesbeam.physics.forward.Forward`).
    nwalkers : int or None
        emcee walkers; None: ``max(32, 4 ndim)`` (see :func:`walker_count`).
    target_ess : float
        Bulk effective sample size every parameter must reach before the sampler stops.
    max_steps : int
        Step budget: the sampler stops here, converged or not.
    min_steps : int
        The sampler takes at least this many steps.
    """

    n_elements: int = 16
    refine_mesh: bool = True
    initial: str = "release"
    nwalkers: int | None = None
    target_ess: float = 1000.0
    max_steps: int = 20_000
    min_steps: int = 300


#: The package defaults: a full fit.
FIT_DEFAULTS = FitSettings()

#: Per sampled model in a diagnosis, which samples several candidate models per round:
#: a shorter chain than a full fit.
DIAGNOSIS_DEFAULTS = dataclasses.replace(
    FIT_DEFAULTS, target_ess=300.0, max_steps=2000, min_steps=200
)

#: The stopping rule of a diagnosis's per-model chains
#: (:func:`bayesbeam.stats.sampling.run_emcee`'s ``n_tau`` and ``tau_rtol``; a full fit
#: keeps their defaults, emcee's 50 τ and a τ settled to 2 % between checks). With the
#: full fit's rule every chain of a whole-record diagnosis ran to ``max_steps`` (Al 60 cm
#: #1, four models: τ 35-48, bulk ESS 1440-2330 for every parameter at 2000 steps, ~5x
#: the target of 300), and both τ criteria were the binding ones: emcee's τ estimate is
#: biased low on short chains (the mean-subtracted autocorrelation; measured on AR(1)
#: walkers of known τ: ~1/3 low at 20 τ, ~1/5 at 50 τ), so it keeps growing by ~2-3 %
#: per check of 100 steps at τ ≈ 45 until the chain is well past 1000 steps, whatever
#: the sampler does. What guards the diagnosis is the bulk ESS (ArviZ, rank-normalised),
#: which must reach ``target_ess`` as before and which is not optimistic where this rule
#: stops (on the same walkers, τ = 45, 68 walkers: the rule stops at 900-1400 steps,
#: where the reported ESS is 0.57-0.80 of the true ``walkers x kept / τ``;
#: ``tests/inference/test_settings.py``).
DIAGNOSIS_STOPPING = MappingProxyType({"n_tau": 20.0, "tau_rtol": 0.05})


def fit_settings(settings: Mapping[str, Any], *, caller: str = "fit") -> dict[str, Any]:
    """Check fit settings given by name and fill in the rest from :data:`FIT_DEFAULTS`.

    Parameters
    ----------
    settings : mapping
        Some fields of :class:`FitSettings`, by name.
    caller : str
        Function named in the error message.

    Returns
    -------
    dict
        Every field of :class:`FitSettings`, in field order.

    Raises
    ------
    TypeError
        For a name that is not a fit setting, as for any unexpected keyword argument.
    """
    names = [f.name for f in dataclasses.fields(FitSettings)]
    for name in settings:
        if name not in names:
            raise TypeError(f"{caller}() got an unexpected keyword argument {name!r}")
    return dataclasses.asdict(dataclasses.replace(FIT_DEFAULTS, **settings))


def walker_count(nwalkers: int | None, ndim: int) -> int:
    """Walkers of an emcee ensemble: ``nwalkers``, or ``max(32, 4 ndim)``; made even.

    Parameters
    ----------
    nwalkers : int or None
        The requested number (``FitSettings.nwalkers``); None for the default.
    ndim : int
        Parameters sampled.

    Returns
    -------
    int
        The number rounded up to even (emcee's ensemble moves split the walkers in
        two halves).
    """
    n = max(32, 4 * ndim) if nwalkers is None else nwalkers
    return n + n % 2


#: Most Hermite elements the commands accept (``--elements``). A fit refines its mesh
#: itself where the data need it (:data:`bayesbeam.inference.mesh.LADDER`: from 16 up to
#: 96 elements) and checks the final mesh against one 1.5 x finer beyond the ladder, so
#: a start of 200, twice the ladder's finest, is checked against 300. Cubic Hermite
#: frequencies converge as (k/N)^4 (physics.md §4): 200 elements resolve the first 50
#: modes as well as the default 16 resolve the first 4 (1.5e-4), more modes than any
#: sensor band holds. Above it the dense state matrices cost gigabytes and minutes per
#: sampler step (:func:`mesh_cost`: 0.9 GB and 12 s at 200 elements, 5.6 GB and 90 s at
#: 500) and resolve no mode a record can show.
MAX_ELEMENTS = 200

#: From this many elements on, the commands say what the mesh costs (about 10 x the
#: default's time per sampler step).
COSTLY_ELEMENTS = 64

# mesh_cost's model, measured on a 2-core machine (one BLAS thread, 32 parameter sets,
# 1280 samples, viscous damping, classical and non-classical): the forward model holds
# about 5.5 dense (4N x 4N) float64 arrays per parameter set at its peak (modal damping,
# state matrix, the sensor band's reduction), and its time grows as N^2.2 between 64 and
# 200 elements (0.8-1.1 s at 64, 2.1-2.8 s at 96, 11.5-12.3 s at 200) above a floor of
# 0.07 s of per-call work.
_ARRAYS_PER_SET = 5.5
_SECONDS_AT_200 = 12.0
_TIME_EXPONENT = 2.2
_SECONDS_FLOOR = 0.07


def mesh_cost(n_elements: int, n_sets: int = 32) -> tuple[float, float]:
    """Estimated peak memory and time of one forward evaluation on a mesh.

    The forward model's state has ``4 N`` entries (two degrees of freedom per node,
    displacement and velocity) and its matrices are dense, so memory grows as ``N^2``
    and time as about ``N^2.2`` (see the measurements above :func:`mesh_cost` in the
    source). One evaluation of ``n_sets`` parameter sets is one sampler step of as many
    walkers (32 by default, :func:`walker_count`).

    Parameters
    ----------
    n_elements : int
        Hermite elements ``N``.
    n_sets : int
        Parameter sets evaluated together.

    Returns
    -------
    memory_bytes : float
        Peak memory of the forward model's arrays, bytes.
    seconds : float
        Wall time on a 2-core machine with one BLAS thread, s (a rough guide: machines
        differ by a few times).
    """
    states = 4 * n_elements
    memory = _ARRAYS_PER_SET * 8.0 * states**2 * n_sets
    seconds = (_SECONDS_FLOOR + _SECONDS_AT_200 * (n_elements / 200) ** _TIME_EXPONENT
               ) * n_sets / 32
    return memory, seconds


def _num(x: float) -> str:
    """Two significant digits, without an exponent (12, 1.5, 0.12; 130 for 128)."""
    return f"{float(f'{x:.2g}'):.0f}" if x >= 10 else f"{x:.2g}"


def _size(nbytes: float) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6)):
        if nbytes >= scale:
            return f"{_num(nbytes / scale)} {unit}"
    return f"{_num(nbytes / 1e3)} kB"


def mesh_cost_text(n_elements: int, n_sets: int = 32) -> str:
    """One clause saying what a mesh costs (:func:`mesh_cost`), for notes and errors.

    Parameters
    ----------
    n_elements : int
        Hermite elements.
    n_sets : int
        Parameter sets per evaluation (walkers per sampler step).

    Returns
    -------
    str
        E.g. for 200 elements ``'800 dense states: about 900 MB and 12 s per evaluation
        of 32 parameter sets (one sampler step), 100 x the default 16 elements' time'``.
    """
    memory, seconds = mesh_cost(n_elements, n_sets)
    _, base = mesh_cost(FIT_DEFAULTS.n_elements, n_sets)
    return (f"{4 * n_elements} dense states: about {_size(memory)} and {_num(seconds)} s "
            f"per evaluation of {n_sets} parameter sets (one sampler step), "
            f"{_num(seconds / base)} x the default {FIT_DEFAULTS.n_elements} elements' time")
