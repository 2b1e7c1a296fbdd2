"""Immutable fit results and their summaries; files in ``result_files``, plots in ``result_plots``.

A :class:`FitResult` bundles the :class:`~bayesbeam.stats.sampling.Chain` (samples in the
sampling space ``u``), the :class:`~bayesbeam.stats.priors.PriorSet` that maps ``u`` to
physical values and was used for the fit (so every result records its priors), the
MAP point, the sampler settings and a provenance record.

The ArviZ tree (:meth:`FitResult.to_inference_data`), ``posterior.nc`` and
``summary.json`` (:meth:`FitResult.save`, :meth:`FitResult.load`) are made in
:mod:`bayesbeam.inference.result_files`, which documents their layout.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
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
    distribution_version,
    finite_json,
    interval_digits,
)
from bayesbeam.inference import result_files
from bayesbeam.inference.result_files import ResultError, plain_mapping
from bayesbeam.physics.models import SIGNAL, parameter_units
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.sampling import Chain

__all__ = ["FitResult", "ResultError", "make_provenance"]

_QUANTILES = INTERVAL_QUANTILES
#: ``units`` of log densities: natural logarithms of densities.
_NAT = "nat"


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


def _frozen_mapping(m: Mapping[str, Any] | None) -> Mapping[str, Any]:
    return MappingProxyType(copy.deepcopy(dict(m or {})))


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
                "mesh": plain_mapping(self.mesh),
                "adequacy": plain_mapping(self.adequacy),
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
        """Build an ArviZ ``DataTree`` (layout: :mod:`bayesbeam.inference.result_files`).

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
        return result_files.to_tree(
            self, posterior_predictive, log_likelihood, observed, prior_samples,
            obs_dim=obs_dim, obs_coords=obs_coords, var_name=var_name,
            prior_seed=prior_seed, rng=rng)

    # -- files (bayesbeam.inference.result_files) -----------------------------------
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
        return result_files.save(self, outdir, idata=idata, summary_from=summary_from,
                                 **idata_kwargs)

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
        return cls(**result_files.fields_from_tree(idata))

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
        return cls.from_inference_data(result_files.read_tree(path))

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
