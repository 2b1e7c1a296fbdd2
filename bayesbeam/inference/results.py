"""Immutable fit results: summaries and ArviZ export (NetCDF); plots in ``result_plots``.

A :class:`FitResult` bundles the :class:`~bayesbeam.stats.sampling.Chain` (samples in the
sampling space ``u``), the :class:`~bayesbeam.stats.priors.PriorSet` that maps ``u`` to
physical values and was used for the fit (so every result records its priors), the
MAP point, the sampler settings and a provenance record.

ArviZ layout written by :meth:`FitResult.to_inference_data` (an ``xarray.DataTree``,
ArviZ 1.x; walkers are the ``chain`` dimension, steps the ``draw`` dimension):

``posterior``                physical parameter values (SI units)
``unconstrained_posterior``  the same draws in the sampling space ``u``
``sample_stats``             ``lp``: log posterior density in ``u`` (Jacobian included)
``log_likelihood``           pointwise log-likelihood ``(chain, draw, time)``, nats
``posterior_predictive``     replicated signals ``(chain, draw', time)`` at a subset
                             ``draw'`` of the posterior's draws (its ``draw`` labels)
``observed_data``            the measured signal on its ``time`` coordinate (s)
``prior``                    prior draws in physical units
root attributes              JSON strings: ``priors``, ``settings``, ``provenance``,
                             ``chain`` (diagnostics), ``map_u``, ``mesh``,
                             ``adequacy``; plain ``model`` and ``signal_unit``

A result that knows the problem it was fitted to (:attr:`FitResult.problem`, see
:meth:`FitResult.with_problem`) writes the complete tree: every group above, at the
draws of :meth:`FitResult.thin` to :func:`~bayesbeam.inference.predictive.loglik_draws`
(at most 1000; posterior, sample_stats and log_likelihood hold the same draws, so that
``arviz.loo`` and ``arviz.compare`` work on it); without one, the groups it is given.
Every variable carries ``units`` (SI, ``"1"`` for a pure number, ``"nat"`` for log
densities; :data:`bayesbeam.physics.models.PARAMETER_UNITS`) and ``long_name``
attributes, and the ``time`` coordinate its unit ``"s"``: they are NetCDF attributes and
survive :meth:`FitResult.save` and :meth:`FitResult.load`.

:meth:`FitResult.save` writes that tree to ``posterior.nc`` (h5netcdf engine) and
the summary to ``summary.json``; :meth:`FitResult.load` reads ``posterior.nc`` back.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import datetime as _dt
import io
import json
import platform
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from bayesbeam._util import (
    INTERVAL_QUANTILES,
    SCHEMA_VERSION,
    atomic_path,
    distribution_version,
    finite_json,
    interval_digits,
    json_default,
    write_text_atomic,
)
from bayesbeam.physics.models import SIGNAL, parameter_units
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.sampling import Chain

__all__ = ["FitResult", "ResultError", "make_provenance"]

_QUANTILES = INTERVAL_QUANTILES
#: ``units`` of log densities: natural logarithms of densities.
_NAT = "nat"


class ResultError(ValueError):
    """Inconsistent result data; the message says what does not match."""


def _dumps(obj: Any, **kw: Any) -> str:
    # allow_nan: tau may be inf when it could not be estimated; json writes Infinity.
    return json.dumps(obj, default=json_default, allow_nan=True, **kw)


def make_provenance(extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Record software versions, platform and time of a fit.

    Parameters
    ----------
    extra : mapping, optional
        Further entries (e.g. the trial file and its hash, the command line).

    Returns
    -------
    dict
        ``created`` (UTC ISO 8601), ``python``, ``platform`` and ``versions``
        (bayesbeam, numpy, scipy, emcee, arviz), plus ``extra``.
    """
    out: dict[str, Any] = {
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "versions": {d: distribution_version(d, "not installed")
                     for d in ("bayesbeam", "numpy", "scipy", "emcee", "arviz")},
    }
    out.update(dict(extra or {}))
    return out


def _local_scheduler() -> Any:
    """Context in which xarray writes with a thread lock, not dask's scheduler's lock.

    Inside a dask.distributed worker xarray locks a write with a ``distributed.Lock``
    named by the target, which must be a path: writing into an in-memory buffer there
    fails ("Semaphore or Lock ... not known"). The buffer is this process's own, so a
    thread lock (dask's synchronous scheduler) is all it needs. Without dask: nothing.
    """
    try:
        import dask
    except ImportError:  # dask is an optional extra: no scheduler to step around
        return contextlib.nullcontext()
    return dask.config.set(scheduler="synchronous")


def _frozen_mapping(m: Mapping[str, Any] | None) -> Mapping[str, Any]:
    return MappingProxyType(copy.deepcopy(dict(m or {})))


def _plain(m: Any) -> Any:
    """Return a frozen mapping (and nested ones) as plain dicts and lists, for JSON."""
    if isinstance(m, Mapping):
        return {str(k): _plain(v) for k, v in m.items()}
    if isinstance(m, (list, tuple)):
        return [_plain(v) for v in m]
    return m


def _named_arrays(value: Any, default_name: str) -> dict[str, np.ndarray]:
    if isinstance(value, Mapping):
        return {str(k): np.asarray(v, dtype=float) for k, v in value.items()}
    if value is None:
        return {}
    return {default_name: np.asarray(value, dtype=float)}


@dataclass(frozen=True, eq=False)
class FitResult:
    """Outcome of one Bayesian calibration (immutable).

    Attributes
    ----------
    model : str
        Model name, e.g. ``"viscous+kv"``.
    chain : Chain
        Post-burn-in samples in the sampling space with diagnostics.
    priors : PriorSet
        Priors used, in parameter order; maps ``u`` to physical values.
    map_u : numpy.ndarray or None, shape (ndim,)
        MAP estimate in the sampling space, if one was computed.
    settings : mapping
        Sampler and likelihood settings (JSON-serialisable values).
    provenance : mapping
        Versions, time, inputs; see :func:`make_provenance`.
    derived : mapping of str to ndarray, shape (nsteps, nwalkers)
        Quantities computed from each sample in physical units (e.g. the
        spatial-hysteresis strength ``a`` when ``eta`` is sampled); summarised and
        stored in the posterior group beside the sampled parameters.
    mesh : mapping
        The mesh-convergence record of the fit
        (:func:`bayesbeam.inference.mesh.converge_mesh`); empty when none was made.
    adequacy : mapping
        Whether the model reproduces the data to its noise
        (:func:`bayesbeam.inference.adequacy.assess`): ``ok``, ``reasons``, figures;
        empty when not assessed.
    signal_unit : str or None
        SI unit of the fitted signal (``"m"``, ``"m/s"`` or ``"m/s^2"``): the unit of the
        data, of ``sigma`` and ``offset``; taken from :attr:`problem` when one is given,
        kept in the saved tree.
    problem : bayesbeam.inference.problem.Problem or None
        The problem that was fitted (trial, model, priors, final mesh), with which
        :meth:`to_inference_data` makes the complete tree; not saved (a loaded result
        gets one again with :meth:`with_problem`). Its parameters and priors must be
        the result's.
    """

    model: str
    chain: Chain
    priors: PriorSet
    map_u: np.ndarray | None = None
    settings: Mapping[str, Any] = field(default_factory=dict)
    provenance: Mapping[str, Any] = field(default_factory=dict)
    derived: Mapping[str, np.ndarray] = field(default_factory=dict)
    mesh: Mapping[str, Any] = field(default_factory=dict)
    adequacy: Mapping[str, Any] = field(default_factory=dict)
    signal_unit: str | None = None
    problem: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.priors, PriorSet):
            object.__setattr__(self, "priors", PriorSet(self.priors))
        if self.problem is not None:
            pb = self.problem
            if tuple(pb.names) != tuple(self.priors.names) or pb.priors != self.priors:
                raise ResultError(
                    f"the problem's parameters {list(pb.names)} or priors are not the "
                    f"result's ({list(self.priors.names)}); pass the problem that was fitted"
                )
            if self.signal_unit is None:
                object.__setattr__(self, "signal_unit", pb.signal_unit)
        if tuple(self.priors.names) != tuple(self.chain.names):
            raise ResultError(
                f"chain parameters {list(self.chain.names)} do not match the priors' "
                f"{list(self.priors.names)} (same names in the same order are required)"
            )
        if self.map_u is not None:
            m = np.array(self.map_u, dtype=float)
            if m.shape != (self.chain.ndim,):
                raise ResultError(f"map_u must have shape ({self.chain.ndim},), got {m.shape}")
            m.setflags(write=False)
            object.__setattr__(self, "map_u", m)
        object.__setattr__(self, "settings", _frozen_mapping(self.settings))
        object.__setattr__(self, "provenance", _frozen_mapping(self.provenance))
        object.__setattr__(self, "mesh", _frozen_mapping(self.mesh))
        object.__setattr__(self, "adequacy", _frozen_mapping(self.adequacy))
        derived = {}
        for name, arr in dict(self.derived).items():
            a = np.array(arr, dtype=float)
            if a.shape != self.chain.samples.shape[:2]:
                raise ResultError(
                    f"derived[{name!r}] must have shape {self.chain.samples.shape[:2]} "
                    f"(nsteps, nwalkers), got {a.shape}"
                )
            a.setflags(write=False)
            derived[name] = a
        object.__setattr__(self, "derived", _frozen_mapping(derived))

    def __reduce__(self) -> tuple[Any, tuple[dict[str, Any]]]:
        """Pickle as plain constructor arguments (the read-only mapping proxies cannot be).

        A result then travels to and from executor workers (processes, Dask) and is
        rebuilt, checks included, by its own constructor: the same arrays and numbers.
        """
        fields = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            fields[f.name] = dict(v) if isinstance(v, MappingProxyType) else v
        return _rebuild, (fields,)

    # -- derived values --------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names in column order."""
        return self.chain.names

    @property
    def map_theta(self) -> np.ndarray | None:
        """MAP in physical units, shape ``(ndim,)``, or ``None``."""
        return None if self.map_u is None else self.priors.to_theta(self.map_u)

    def theta_samples(self) -> np.ndarray:
        """Posterior samples in physical units.

        Returns
        -------
        numpy.ndarray, shape (nsteps, nwalkers, ndim)
        """
        return self.priors.to_theta(self.chain.samples)

    def summary(self) -> dict[str, dict[str, float]]:
        """Posterior mean, standard deviation and 5/50/95 % quantiles per parameter.

        Returns
        -------
        dict
            ``{name: {"mean", "sd", "q05", "q50", "q95"}}`` in physical (SI) units.
        """
        flat = self.theta_samples().reshape(-1, self.chain.ndim)
        q = np.quantile(flat, list(_QUANTILES.values()), axis=0)
        out: dict[str, dict[str, float]] = {}
        for j, name in enumerate(self.names):
            row = {"mean": float(np.mean(flat[:, j])), "sd": float(np.std(flat[:, j], ddof=1))}
            row.update({k: float(q[i, j]) for i, k in enumerate(_QUANTILES)})
            out[name] = row
        for name, arr in self.derived.items():
            a = arr.reshape(-1)
            qs = np.quantile(a, list(_QUANTILES.values()))
            row = {"mean": float(np.mean(a)), "sd": float(np.std(a, ddof=1))}
            row.update({k: float(qs[i]) for i, k in enumerate(_QUANTILES)})
            out[name] = row
        return out

    def diagnostics(self) -> dict[str, Any]:
        """Convergence diagnostics of the chain.

        Returns
        -------
        dict
            ``ess_min``, ``tau_max`` (steps), ``rhat_max``, ``converged``,
            ``seconds``, ``ess_per_second`` (smallest ESS per second of sampling),
            ``n_calls``, ``acceptance_mean``, ``burn_in``,
            ``n_steps_total``, ``nwalkers``, ``n_samples`` and per-parameter
            ``tau``, ``ess``, ``rhat`` dicts.
        """
        c = self.chain
        return {
            "ess_min": c.ess_min,
            "tau_max": c.tau_max,
            "rhat_max": c.rhat_max,
            "converged": bool(c.converged),
            "seconds": float(c.seconds),
            "ess_per_second": float(c.ess_per_second),
            "n_calls": int(c.n_calls),
            "acceptance_mean": float(np.mean(c.acceptance_fraction)),
            "burn_in": int(c.burn_in),
            "n_steps_total": int(c.n_steps_total),
            "nwalkers": int(c.nwalkers),
            "n_samples": int(c.nsteps * c.nwalkers),
            "tau": dict(zip(self.names, map(float, c.tau), strict=True)),
            "ess": dict(zip(self.names, map(float, c.ess), strict=True)),
            "rhat": dict(zip(self.names, map(float, c.rhat), strict=True)),
        }

    def units(self) -> dict[str, str]:
        """SI unit of every entry of :meth:`summary` (``"1"`` for a pure number).

        Returns
        -------
        dict of str to str
            From :data:`bayesbeam.physics.models.PARAMETER_UNITS`; ``sigma`` and
            ``offset`` take the trial's signal unit (``""`` when it is not known).
        """
        sig = self.signal_unit or None
        units = {name: parameter_units(name, sig, default=("", ""))[0] for name in self.summary()}
        return {name: ("" if u == SIGNAL else u) for name, u in units.items()}

    def to_json_dict(self) -> dict[str, Any]:
        """Summary record for ``summary.json`` and ``bayesbeam fit --json``.

        Returns
        -------
        dict
            Keys ``model``, ``posterior`` (see :meth:`summary`), ``ess_min``,
            ``tau_max``, ``rhat_max``, ``converged``, ``seconds``, plus
            ``diagnostics``, ``map`` (physical, or ``None``), ``units`` (of every
            ``posterior`` entry, SI; :meth:`units`), ``mesh``, ``adequacy``,
            ``priors``, ``settings`` and ``provenance``. Non-finite numbers (e.g. ``tau`` of a
            run too short to estimate it) become ``None`` so the record is strict JSON.
        """
        d = self.diagnostics()
        mt = self.map_theta
        return finite_json(
            {
                "schema_version": SCHEMA_VERSION,
                "model": self.model,
                "posterior": self.summary(),
                "ess_min": d["ess_min"],
                "tau_max": d["tau_max"],
                "rhat_max": d["rhat_max"],
                "converged": d["converged"],
                "seconds": d["seconds"],
                "diagnostics": d,
                "map": None if mt is None else dict(zip(self.names, map(float, mt), strict=True)),
                "units": self.units(),
                "mesh": _plain(self.mesh),
                "adequacy": _plain(self.adequacy),
                "priors": self.priors.to_dict(),
                "settings": dict(self.settings),
                "provenance": dict(self.provenance),
            }
        )

    def __str__(self) -> str:
        c = self.chain
        state = "converged" if c.converged else "NOT converged"
        head = (
            f"FitResult: model {self.model!r} ({state}; {c.n_steps_total} steps x "
            f"{c.nwalkers} walkers, burn-in {c.burn_in}, {c.seconds:.1f} s; "
            f"ESS min {c.ess_min:.0f}, {c.ess_per_second:.3g} per s)"
        )
        cols = ("mean", "sd", "q05", "q50", "q95")
        width = max(5, *(len(n) for n in self.names))
        lines = [
            head,
            f"{'param':<{width}} "
            + " ".join(f"{k:>11}" for k in cols)
            + f" {'ess':>7} {'tau':>7} {'rhat':>6}",
        ]
        for j, (name, row) in enumerate(self.summary().items()):
            diag = (
                f" {c.ess[j]:>7.0f} {c.tau[j]:>7.1f} {c.rhat[j]:>6.3f}"
                if j < c.ndim
                else "   (derived)"
            )
            # Enough digits that the interval's ends print apart (not 5.236e+10 four times).
            d = interval_digits(row["q50"], row["q05"], row["q95"], minimum=4)
            cells = [f"{row[k]:#.{d}g}" if k != "sd" else f"{row[k]:.3g}" for k in cols]
            lines.append(f"{name:<{width}} " + " ".join(f"{x:>11}" for x in cells) + diag)
        if self.mesh:
            lines.append(f"mesh: {self.mesh.get('summary', '')}")
        if self.adequacy:
            lines.append(f"adequacy: {self.adequacy.get('summary', '')}")
        return "\n".join(lines)

    def with_problem(self, problem: Any) -> FitResult:
        """Return the result with the problem it was fitted to (for the complete tree).

        Parameters
        ----------
        problem : bayesbeam.inference.problem.Problem or bayesbeam.trials.trial.Trial
            The fitted problem, or the trial it was fitted to: the problem is then
            rebuilt from the result's model, priors, ``settings["n_elements"]`` (the
            fit's final mesh) and ``settings["initial"]``.

        Returns
        -------
        FitResult
            A copy with :attr:`problem` and :attr:`signal_unit` set.

        Raises
        ------
        ResultError
            If the problem's parameters or priors are not the result's, or a trial is
            given to a result whose settings lack ``n_elements``.
        """
        from bayesbeam.trials.trial import Trial

        if isinstance(problem, Trial):
            from bayesbeam.inference.problem import Problem

            if "n_elements" not in self.settings:
                raise ResultError("the result's settings lack n_elements: pass the fitted "
                                  "Problem instead of the trial")
            problem = Problem(problem, self.model, self.priors,
                              n_elements=int(self.settings["n_elements"]),
                              initial=str(self.settings.get("initial", "release")))
        return dataclasses.replace(self, problem=problem, signal_unit=problem.signal_unit)

    def thin(self, max_draws: int) -> FitResult:
        """Keep at most ``max_draws`` draws: evenly spaced steps (the last included), all walkers.

        Parameters
        ----------
        max_draws : int
            Upper bound on steps × walkers; at least one step (all walkers) is kept.

        Returns
        -------
        FitResult
            ``self`` when nothing is dropped; otherwise a copy with every ``k``-th step
            of the chain and of :attr:`derived`, ``k = ceil(nsteps / (max_draws //
            nwalkers))``, counted back from the last step (diagnostics, MAP and problem
            unchanged).
        """
        c = self.chain
        keep = max(1, int(max_draws) // c.nwalkers)
        step = -(-c.nsteps // keep)  # ceil: at most `keep` steps remain
        if step == 1:
            return self
        sel = slice((c.nsteps - 1) % step, None, step)
        chain = dataclasses.replace(c, samples=c.samples[sel], log_prob=c.log_prob[sel])
        derived = {k: v[sel] for k, v in self.derived.items()}
        return dataclasses.replace(self, chain=chain, derived=derived)

    # -- ArviZ -----------------------------------------------------------------------
    def to_inference_data(
        self,
        posterior_predictive: Any = None,
        log_likelihood: Any = None,
        observed: Any = None,
        prior_samples: int | np.ndarray | None = None,
        *,
        obs_dim: str = "time",
        obs_coords: Any = None,
        var_name: str = "y",
        prior_seed: int | None = None,
        rng: np.random.Generator | None = None,
    ):
        """Build an ArviZ ``DataTree`` (layout in the module docstring).

        With :attr:`problem` set, every group that is not given is made from it: the
        result is thinned to :func:`~bayesbeam.inference.predictive.loglik_draws` draws
        (unless ``log_likelihood`` is given, which must then match this result's
        draws), the pointwise log-likelihood is computed at every kept draw
        (:func:`~bayesbeam.inference.predictive.log_likelihood_group`), replicated data
        at a subset of them (:func:`~bayesbeam.inference.predictive.predictive_group`),
        the observed data on the trial's time axis (s) and
        :data:`~bayesbeam.inference.predictive.PRIOR_DRAWS` prior draws. Without a
        problem, only the groups given are added.

        Parameters
        ----------
        posterior_predictive : array_like or mapping, optional
            Simulated observations, shape ``(nwalkers, ndraws, N)`` (``ndraws`` may
            be a subset of the steps); a mapping gives several variables.
        log_likelihood : array_like or mapping, optional
            Pointwise log-likelihood in nats, shape ``(nwalkers, nsteps, N)`` matching
            the posterior draws (needed by ``arviz.loo``).
        observed : array_like or mapping, optional
            Measured signal, shape ``(N,)``, SI units of the trial's quantity.
        prior_samples : int or array_like, optional
            Number of prior draws to make from :attr:`priors`, or prior draws in
            physical units, shape ``(n, ndim)``.
        obs_dim : str, default "time"
            Dimension name of the observation axis.
        obs_coords : array_like, optional
            Coordinate values of the observation axis (sample times in s).
        var_name : str, default "y"
            Variable name for array (non-mapping) inputs.
        prior_seed : int, optional
            Seed for drawing ``prior_samples`` (default: the chain's seed).
        rng : numpy.random.Generator, optional
            Source of the noise of the posterior-predictive draws made from
            :attr:`problem` (default: seeded by the chain's seed, so that a result
            gives the same tree every time).

        Returns
        -------
        xarray.DataTree
            Every variable with ``units`` and ``long_name`` attributes where its unit is
            known (a parameter of :data:`~bayesbeam.physics.models.PARAMETER_UNITS`;
            the signal's unit from :attr:`signal_unit`).

        Raises
        ------
        ResultError
            If array shapes do not match the chain or each other.
        """
        pb = self.problem
        if pb is None:
            return self._tree(posterior_predictive, log_likelihood, observed, prior_samples,
                              obs_dim=obs_dim, obs_coords=obs_coords, var_name=var_name,
                              prior_seed=prior_seed)
        from bayesbeam.inference.predictive import (
            PPC_DRAWS,
            PRIOR_DRAWS,
            log_likelihood_group,
            loglik_draws,
            predictive_group,
            predictive_steps,
        )

        res = self
        if log_likelihood is None:
            res = self.thin(loglik_draws(pb.data.size, self.chain.nwalkers))
            log_likelihood = log_likelihood_group(pb, res.chain.samples)
        c = res.chain
        ppc_draws = None
        if posterior_predictive is None:
            if rng is None:
                rng = np.random.default_rng(np.random.SeedSequence([int(c.seed), 2]))
            posterior_predictive = predictive_group(pb, c.samples, rng, max_draws=PPC_DRAWS)
            ppc_draws = predictive_steps(c.nsteps, c.nwalkers, PPC_DRAWS)
        if observed is None:
            observed = np.asarray(pb.data, dtype=float)
            if obs_coords is None:
                obs_coords = np.asarray(pb.trial.times, dtype=float)
        tree = res._tree(posterior_predictive, log_likelihood, observed,
                         PRIOR_DRAWS if prior_samples is None else prior_samples,
                         obs_dim=obs_dim, obs_coords=obs_coords, var_name=var_name,
                         prior_seed=prior_seed)
        if ppc_draws is not None:
            # Label the replicated draws with the posterior draws they were made from.
            node = tree["posterior_predictive"]
            node.dataset = node.to_dataset(inherit=False).assign_coords(draw=ppc_draws)
        return tree

    def _tree(
        self,
        posterior_predictive: Any,
        log_likelihood: Any,
        observed: Any,
        prior_samples: int | np.ndarray | None,
        *,
        obs_dim: str,
        obs_coords: Any,
        var_name: str,
        prior_seed: int | None,
    ):
        """Build the tree from the given groups (:meth:`to_inference_data` without a problem)."""
        import arviz  # deferred: importing ArviZ takes ~2 s

        c = self.chain
        theta = np.swapaxes(self.theta_samples(), 0, 1)  # (walker=chain, step=draw, ndim)
        u = np.swapaxes(c.samples, 0, 1)
        groups: dict[str, dict[str, np.ndarray]] = {
            "posterior": {
                **{n: theta[..., j] for j, n in enumerate(self.names)},
                **{n: np.swapaxes(a, 0, 1) for n, a in self.derived.items()},
            },
            "unconstrained_posterior": {n: u[..., j] for j, n in enumerate(self.names)},
            "sample_stats": {"lp": np.swapaxes(c.log_prob, 0, 1)},
        }
        dims: dict[str, list[str]] = {}

        def obs_group(key: str, value: Any, sample: bool) -> None:
            arrays = _named_arrays(value, var_name)
            for name, a in arrays.items():
                want = 3 if sample else 1
                if a.ndim != want:
                    shape = "(nwalkers, ndraws, N)" if sample else "(N,)"
                    raise ResultError(f"{key}[{name!r}] must have shape {shape}, got {a.shape}")
                if sample and a.shape[0] != c.nwalkers:
                    raise ResultError(
                        f"{key}[{name!r}] has {a.shape[0]} chains; the posterior has "
                        f"{c.nwalkers} walkers"
                    )
                if key == "log_likelihood" and a.shape[:2] != (c.nwalkers, c.nsteps):
                    raise ResultError(
                        f"log_likelihood[{name!r}] must match the posterior draws "
                        f"{(c.nwalkers, c.nsteps)}, got {a.shape[:2]}"
                    )
                dims[name] = [obs_dim]
            if arrays:
                groups[key] = arrays

        obs_group("posterior_predictive", posterior_predictive, True)
        obs_group("log_likelihood", log_likelihood, True)
        obs_group("observed_data", observed, False)
        obs_keys = ("posterior_predictive", "log_likelihood", "observed_data")
        lengths = {a.shape[-1] for k in obs_keys for a in groups.get(k, {}).values()}
        if len(lengths) > 1:
            raise ResultError(f"observation axes differ in length: {sorted(lengths)}")
        coords = {}
        if obs_coords is not None:
            oc = np.asarray(obs_coords)
            if lengths and oc.shape != (next(iter(lengths)),):
                raise ResultError(
                    f"obs_coords has shape {oc.shape}; the observations have "
                    f"{next(iter(lengths))} points"
                )
            coords[obs_dim] = oc

        if prior_samples is not None:
            if isinstance(prior_samples, (int, np.integer)) and not isinstance(prior_samples, bool):
                rng = np.random.default_rng(c.seed if prior_seed is None else prior_seed)
                ps = self.priors.sample(rng, int(prior_samples))
            else:
                ps = np.asarray(prior_samples, dtype=float)
            if ps.ndim != 2 or ps.shape[1] != c.ndim:
                raise ResultError(f"prior_samples must be (n, {c.ndim}), got {ps.shape}")
            groups["prior"] = {n: ps[None, :, j] for j, n in enumerate(self.names)}

        attrs = {
            "/": {
                "model": self.model,
                "parameters": _dumps(list(self.names)),
                "priors": _dumps(self.priors.to_dict()),
                "settings": _dumps(dict(self.settings)),
                "provenance": _dumps(dict(self.provenance)),
                "chain": _dumps(_chain_meta(c)),
                "map_u": _dumps(None if self.map_u is None else self.map_u),
                "mesh": _dumps(_plain(self.mesh)),
                "adequacy": _dumps(_plain(self.adequacy)),
            }
        }
        if self.signal_unit is not None:
            attrs["/"]["signal_unit"] = self.signal_unit
        # check_conventions=False: ArviZ warns when a group has more chains than draws,
        # which is normal here (e.g. 32 walkers, 10 posterior-predictive draws); the
        # dims are named explicitly, so the heuristic has nothing to catch.
        tree = arviz.from_dict(
            groups,
            dims=dims or None,
            coords=coords or None,
            attrs=attrs,
            check_conventions=False,
        )
        for key in groups:
            node = tree[key]
            ds = node.to_dataset(inherit=False)
            ds = ds.assign({v: ds[v].assign_attrs(self._variable_attrs(key, str(v)))
                            for v in ds.data_vars})
            if obs_dim in ds.coords:
                ds = ds.assign_coords({obs_dim: ds[obs_dim].assign_attrs(
                    units="s" if obs_dim == "time" else "1",
                    long_name="time of the sample" if obs_dim == "time" else "sample index")})
            node.dataset = ds
        return tree

    def _variable_attrs(self, group: str, name: str) -> dict[str, str]:
        """``units`` and ``long_name`` of one variable of the tree (empty if unknown)."""
        sig = self.signal_unit
        if group == "log_likelihood":
            return {"units": _NAT, "long_name": "pointwise log-likelihood"
                    + (" (conditional on the previous sample)" if "rho" in self.names else "")}
        if group == "sample_stats":
            return {"units": _NAT, "long_name": "log posterior density in the sampling space u "
                    "(unnormalised, Jacobian included)"} if name == "lp" else {}
        if group in ("posterior_predictive", "observed_data"):
            what = ("replicated signal: model plus a draw of the fitted noise"
                    if group == "posterior_predictive" else "measured signal")
            return {"long_name": what} if sig is None else {"units": sig, "long_name": what}
        unit, meaning = parameter_units(name, sig, default=("", ""))
        if group == "unconstrained_posterior" and unit not in ("", SIGNAL):
            unit, meaning = _sampling_space_attrs(self.priors[name], name, unit)
        if unit in ("", SIGNAL):
            return {"long_name": meaning} if meaning else {}
        return {"units": unit, "long_name": meaning}

    # -- files -----------------------------------------------------------------------
    def save(
        self, outdir: str | Path, *, idata: Any = None, summary_from: FitResult | None = None,
        **idata_kwargs: Any,
    ) -> dict[str, Path]:
        """Write ``posterior.nc`` (ArviZ NetCDF) and ``summary.json`` into ``outdir``.

        Parameters
        ----------
        outdir : str or pathlib.Path
            Output directory, created if missing; existing files are replaced.
        idata : xarray.DataTree, optional
            Tree to write; default ``self.to_inference_data(**idata_kwargs)``.
        summary_from : FitResult, optional
            The result whose summary ``summary.json`` holds (default this one): a
            thinned result (the draws of the pointwise log-likelihood) saves its draws
            and the full chain's summary.
        **idata_kwargs
            Passed to :meth:`to_inference_data`.

        Returns
        -------
        dict
            ``{"netcdf": path, "summary": path}``.
        """
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        if idata is None:
            idata = self.to_inference_data(**idata_kwargs)
        nc = outdir / "posterior.nc"
        _require_h5netcdf()
        # Built in memory, then written as plain bytes: a failing write (full disk) is
        # then an ordinary OSError, never a half-written HDF5 file that the HDF5 library
        # tries to close again at exit (that ended in a segmentation fault).
        buf = io.BytesIO()
        with _local_scheduler():
            idata.to_netcdf(buf, engine="h5netcdf")
        with atomic_path(nc) as tmp:
            tmp.write_bytes(buf.getvalue())
        js = outdir / "summary.json"
        text = json.dumps((summary_from or self).to_json_dict(), default=json_default,
                          allow_nan=False, indent=2)
        write_text_atomic(js, text + "\n")
        return {"netcdf": nc, "summary": js}

    @classmethod
    def from_inference_data(cls, idata: Any) -> FitResult:
        """Rebuild a result from a tree made by :meth:`to_inference_data`.

        Parameters
        ----------
        idata : xarray.DataTree

        Returns
        -------
        FitResult

        Raises
        ------
        ResultError
            If the tree lacks the groups or attributes written by this module.
        """
        try:
            a = idata.attrs
            names = json.loads(a["parameters"])
            meta = json.loads(a["chain"])
            up = idata["unconstrained_posterior"]
            lp = np.asarray(idata["sample_stats"]["lp"].values)
            u = np.stack([np.asarray(up[n].values) for n in names], axis=-1)
        except KeyError as exc:
            raise ResultError(
                f"not a bayesbeam result tree (missing {exc}); it must come from "
                "FitResult.to_inference_data"
            ) from None
        chain = Chain(
            samples=np.swapaxes(u, 0, 1),
            log_prob=np.swapaxes(lp, 0, 1),
            names=tuple(names),
            tau=np.asarray(meta["tau"], dtype=float),
            ess=np.asarray(meta["ess"], dtype=float),
            rhat=np.asarray(meta["rhat"], dtype=float),
            acceptance_fraction=np.asarray(meta["acceptance_fraction"], dtype=float),
            n_calls=int(meta["n_calls"]),
            converged=bool(meta["converged"]),
            seconds=float(meta["seconds"]),
            burn_in=int(meta["burn_in"]),
            seed=int(meta["seed"]),
            thin=int(meta["thin"]),
            n_steps_total=int(meta["n_steps_total"]),
        )
        map_u = json.loads(a["map_u"])
        post = idata["posterior"]
        derived = {
            n: np.swapaxes(np.asarray(post[n].values), 0, 1)
            for n in post.data_vars
            if n not in names
        }
        return cls(
            derived=derived,
            model=str(a["model"]),
            chain=chain,
            priors=PriorSet.from_dict(json.loads(a["priors"])),
            map_u=None if map_u is None else np.asarray(map_u, dtype=float),
            settings=json.loads(a["settings"]),
            provenance=json.loads(a["provenance"]),
            # Results written before these checks existed have neither attribute.
            mesh=json.loads(a["mesh"]) if "mesh" in a else {},
            adequacy=json.loads(a["adequacy"]) if "adequacy" in a else {},
            signal_unit=str(a["signal_unit"]) if "signal_unit" in a else None,
        )

    @classmethod
    def load(cls, path: str | Path) -> FitResult:
        """Read a result saved by :meth:`save` (its directory or ``posterior.nc``).

        Parameters
        ----------
        path : str or pathlib.Path

        Returns
        -------
        FitResult
        """
        import arviz

        path = Path(path)
        if path.is_dir():
            path = path / "posterior.nc"
        if not path.is_file():
            raise ResultError(f"no result file at {path}; expected FitResult.save output")
        _require_h5netcdf()
        return cls.from_inference_data(arviz.from_netcdf(path, engine="h5netcdf"))

    # -- plots (bayesbeam.inference.result_plots) ---------------------------------------
    def plot_corner(self, path: str | Path, *, truths: Any = None, dpi: int = 120,
                    names: Any = None) -> Path:
        """Corner plot of the physical posterior (5/50/95 % marks; corner package).

        See :func:`bayesbeam.inference.result_plots.plot_corner`.

        Parameters
        ----------
        path : str or pathlib.Path
            Image file; the format follows the suffix.
        truths : array_like, optional
            Reference values, one per plotted parameter.
        dpi : int, default 120
        names : sequence of str, optional
            Plot only these sampled parameters, in this order.

        Returns
        -------
        pathlib.Path
        """
        from bayesbeam.inference.result_plots import plot_corner

        return plot_corner(self, path, truths=truths, dpi=dpi, names=names)

    def plot_trace(self, path: str | Path, *, dpi: int = 120, max_walkers: int = 64) -> Path:
        """Trace plot: walkers against step, and marginal histograms.

        See :func:`bayesbeam.inference.result_plots.plot_trace`.

        Parameters
        ----------
        path : str or pathlib.Path
            Image file.
        dpi : int, default 120
        max_walkers : int, default 64

        Returns
        -------
        pathlib.Path
        """
        from bayesbeam.inference.result_plots import plot_trace

        return plot_trace(self, path, dpi=dpi, max_walkers=max_walkers)


def _rebuild(fields: dict[str, Any]) -> FitResult:
    """Unpickle a :class:`FitResult` (see :meth:`FitResult.__reduce__`)."""
    return FitResult(**fields)


def _sampling_space_attrs(prior: Any, name: str, unit: str) -> tuple[str, str]:
    """Return the unit and meaning of a parameter in the sampling space ``u`` of its prior.

    Log-space families sample ``u = ln(x / 1 unit)`` and a logit-Uniform the log-odds of
    the position in its range (both pure numbers); the identity transforms keep ``x``.
    """
    from bayesbeam.stats.families import HalfNormal, LogNormal, LogUniform, Uniform

    if isinstance(prior, (LogUniform, LogNormal, HalfNormal)):
        return "1", f"ln({name} / 1 {unit}): {name} in the sampling space u"
    if isinstance(prior, Uniform) and prior.transform == "logit":
        return "1", f"log-odds of {name} in its prior's range: {name} in the sampling space u"
    return unit, f"{name} in the sampling space u (identity transform)"


def _chain_meta(c: Chain) -> dict[str, Any]:
    return {
        "tau": c.tau.tolist(),  # inf (tau not estimable) is kept: json writes Infinity
        "ess": c.ess.tolist(),
        "rhat": c.rhat.tolist(),
        "acceptance_fraction": c.acceptance_fraction.tolist(),
        "n_calls": c.n_calls,
        "converged": bool(c.converged),
        "seconds": c.seconds,
        "burn_in": c.burn_in,
        "seed": c.seed,
        "thin": c.thin,
        "n_steps_total": c.n_steps_total,
    }


def _require_h5netcdf() -> None:
    try:
        import h5netcdf  # noqa: F401
    except ImportError:
        raise ImportError(
            "writing/reading NetCDF results needs the 'h5netcdf' package: pip install h5netcdf"
        ) from None
