"""Immutable fit results: summaries, ArviZ export (NetCDF) and plots.

A :class:`FitResult` bundles the :class:`~bayesbeam.stats.sampling.Chain` (samples in the
sampling space ``u``), the :class:`~bayesbeam.stats.priors.PriorSet` that maps ``u`` to
physical values and was used for the fit (so every result records its priors), the
MAP point, the sampler settings and a provenance record.

ArviZ layout written by :meth:`FitResult.to_inference_data` (an ``xarray.DataTree``,
ArviZ 1.x; walkers are the ``chain`` dimension, steps the ``draw`` dimension):

``posterior``                physical parameter values (SI units)
``unconstrained_posterior``  the same draws in the sampling space ``u``
``sample_stats``             ``lp``: log posterior density in ``u`` (Jacobian included)
``log_likelihood``           pointwise log-likelihood ``(chain, draw, obs)``, if given
``posterior_predictive``     simulated signals ``(chain, draw', obs)``, if given
``observed_data``            the measured signal, if given
``prior``                    prior draws in physical units, if asked
root attributes              JSON strings: ``priors``, ``settings``, ``provenance``,
                             ``chain`` (diagnostics), ``map_u``, ``mesh``,
                             ``adequacy``; plain ``model``

:meth:`FitResult.save` writes that tree to ``posterior.nc`` (h5netcdf engine) and
the summary to ``summary.json``; :meth:`FitResult.load` reads ``posterior.nc`` back.
"""

from __future__ import annotations

import contextlib
import copy
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
    atomic_path,
    distribution_version,
    finite_json,
    json_default,
    write_text_atomic,
)
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.sampling import Chain

__all__ = ["FitResult", "ResultError", "make_provenance"]

_QUANTILES = {"q05": 0.05, "q50": 0.5, "q95": 0.95}


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

    def __post_init__(self) -> None:
        if not isinstance(self.priors, PriorSet):
            object.__setattr__(self, "priors", PriorSet(self.priors))
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
            ``seconds``, ``n_calls``, ``acceptance_mean``, ``burn_in``,
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

    def to_json_dict(self) -> dict[str, Any]:
        """Summary record for ``summary.json`` and ``bayesbeam fit --json``.

        Returns
        -------
        dict
            Keys ``model``, ``posterior`` (see :meth:`summary`), ``ess_min``,
            ``tau_max``, ``rhat_max``, ``converged``, ``seconds``, plus
            ``diagnostics``, ``map`` (physical, or ``None``), ``mesh``, ``adequacy``,
            ``priors``, ``settings`` and ``provenance``. Non-finite numbers (e.g. ``tau`` of a
            run too short to estimate it) become ``None`` so the record is strict JSON.
        """
        d = self.diagnostics()
        mt = self.map_theta
        return finite_json(
            {
                "model": self.model,
                "posterior": self.summary(),
                "ess_min": d["ess_min"],
                "tau_max": d["tau_max"],
                "rhat_max": d["rhat_max"],
                "converged": d["converged"],
                "seconds": d["seconds"],
                "diagnostics": d,
                "map": None if mt is None else dict(zip(self.names, map(float, mt), strict=True)),
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
            f"{c.nwalkers} walkers, burn-in {c.burn_in}, {c.seconds:.1f} s)"
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
            lines.append(f"{name:<{width}} " + " ".join(f"{row[k]:>11.4g}" for k in cols) + diag)
        if self.mesh:
            lines.append(f"mesh: {self.mesh.get('summary', '')}")
        if self.adequacy:
            lines.append(f"adequacy: {self.adequacy.get('summary', '')}")
        return "\n".join(lines)

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
    ):
        """Build an ArviZ ``DataTree`` (layout in the module docstring).

        Parameters
        ----------
        posterior_predictive : array_like or mapping, optional
            Simulated observations, shape ``(nwalkers, ndraws, N)`` (``ndraws`` may
            be a subset of the steps); a mapping gives several variables.
        log_likelihood : array_like or mapping, optional
            Pointwise log-likelihood, shape ``(nwalkers, nsteps, N)`` matching the
            posterior draws (needed by ``arviz.loo``).
        observed : array_like or mapping, optional
            Measured signal, shape ``(N,)``.
        prior_samples : int or array_like, optional
            Number of prior draws to make from :attr:`priors`, or prior draws in
            physical units, shape ``(n, ndim)``.
        obs_dim : str, default "time"
            Dimension name of the observation axis.
        obs_coords : array_like, optional
            Coordinate values of the observation axis (e.g. sample times in s).
        var_name : str, default "y"
            Variable name for array (non-mapping) inputs.
        prior_seed : int, optional
            Seed for drawing ``prior_samples`` (default: the chain's seed).

        Returns
        -------
        xarray.DataTree

        Raises
        ------
        ResultError
            If array shapes do not match the chain or each other.
        """
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
        # check_conventions=False: ArviZ warns when a group has more chains than draws,
        # which is normal here (e.g. 32 walkers, 10 posterior-predictive draws); the
        # dims are named explicitly, so the heuristic has nothing to catch.
        return arviz.from_dict(
            groups,
            dims=dims or None,
            coords=coords or None,
            attrs=attrs,
            check_conventions=False,
        )

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

    # -- plots -----------------------------------------------------------------------
    def plot_corner(self, path: str | Path, *, truths: Any = None, dpi: int = 120) -> Path:
        """Corner plot of the physical posterior (corner package) with 5/50/95 % marks.

        Parameters
        ----------
        path : str or pathlib.Path
            Image file; the format follows the suffix (``.png``, ``.pdf``, ...).
        truths : array_like, optional
            Reference values (e.g. the truth of a synthetic trial), shape ``(ndim,)``;
            ``None`` entries are skipped.
        dpi : int, default 120

        Returns
        -------
        pathlib.Path
        """
        import corner
        from matplotlib.figure import Figure

        # A bare Figure renders with the Agg canvas and leaves pyplot's global
        # state and backend untouched (no import-time or global side effects).
        nd = self.chain.ndim
        fig = Figure(figsize=(2.2 * nd + 1, 2.2 * nd + 1))
        flat = self.theta_samples().reshape(-1, nd)
        corner.corner(
            flat,
            labels=list(self.names),
            quantiles=list(_QUANTILES.values()),
            show_titles=True,
            title_fmt=".3g",
            truths=None if truths is None else list(truths),
            fig=fig,
        )
        fig.suptitle(f"{self.model}: posterior ({flat.shape[0]} samples)")
        path = Path(path)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
        return path

    def plot_trace(self, path: str | Path, *, dpi: int = 120, max_walkers: int = 64) -> Path:
        """Trace plot: walkers' physical values against step, and marginal histograms.

        Parameters
        ----------
        path : str or pathlib.Path
            Image file.
        dpi : int, default 120
        max_walkers : int, default 64
            Draw at most this many walkers (all are used for the histograms).

        Returns
        -------
        pathlib.Path
        """
        from matplotlib.figure import Figure

        c = self.chain
        th = self.theta_samples()
        steps = c.burn_in + c.thin * np.arange(c.nsteps)
        fig = Figure(figsize=(10, 1.9 * c.ndim + 0.8), layout="constrained")
        axes = fig.subplots(c.ndim, 2, squeeze=False, width_ratios=[4, 1])
        for j, name in enumerate(self.names):
            ax, hx = axes[j]
            ax.plot(steps, th[:, :max_walkers, j], lw=0.4, alpha=0.4, color="k")
            ax.set_ylabel(name)
            hx.hist(th[:, :, j].ravel(), bins=50, orientation="horizontal", color="0.4")
            hx.set_ylim(ax.get_ylim())
            hx.tick_params(labelleft=False)
        axes[-1, 0].set_xlabel("step (after burn-in)")
        fig.suptitle(
            f"{self.model}: traces (tau_max {c.tau_max:.1f}, ESS min {c.ess_min:.0f}, "
            f"R-hat max {c.rhat_max:.3f})"
        )
        path = Path(path)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
        return path


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
