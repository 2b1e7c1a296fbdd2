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
from typing import Any

__all__ = [
    "DIAGNOSIS_DEFAULTS",
    "FIT_DEFAULTS",
    "FitSettings",
    "fit_settings",
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
