"""A fit result's files: the ArviZ tree, ``posterior.nc`` and ``summary.json``.

Functions of a :class:`~bayesbeam.inference.results.FitResult`, which calls them from
:meth:`~bayesbeam.inference.results.FitResult.to_inference_data`,
:meth:`~bayesbeam.inference.results.FitResult.save` and
:meth:`~bayesbeam.inference.results.FitResult.load`; this module does not import that
one (it returns the fields a result is rebuilt from).

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
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import atomic_path, json_default, write_text_atomic
from bayesbeam.physics.models import SIGNAL, parameter_units
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.sampling import Chain

__all__ = ["ResultError", "fields_from_tree", "plain_mapping", "read_tree", "save", "to_tree"]

_NAT = "nat"


class ResultError(ValueError):
    """Inconsistent result data; the message says what does not match."""


def _dumps(obj: Any, **kw: Any) -> str:
    # allow_nan: tau may be inf when it could not be estimated; json writes Infinity.
    return json.dumps(obj, default=json_default, allow_nan=True, **kw)


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


def plain_mapping(m: Any) -> Any:
    """Return a frozen mapping (and nested ones) as plain dicts and lists, for JSON."""
    if isinstance(m, Mapping):
        return {str(k): plain_mapping(v) for k, v in m.items()}
    if isinstance(m, (list, tuple)):
        return [plain_mapping(v) for v in m]
    return m


def _named_arrays(value: Any, default_name: str) -> dict[str, np.ndarray]:
    if isinstance(value, Mapping):
        return {str(k): np.asarray(v, dtype=float) for k, v in value.items()}
    if value is None:
        return {}
    return {default_name: np.asarray(value, dtype=float)}


def to_tree(
    result: Any,
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
) -> Any:
    """Build the ArviZ ``DataTree`` of ``result`` (layout in the module docstring).

    Parameters and behaviour: :meth:`bayesbeam.inference.results.FitResult.to_inference_data`,
    which calls this with the result as ``result``.

    Returns
    -------
    xarray.DataTree
    """
    pb = result.problem
    if pb is None:
        return _tree(result, posterior_predictive, log_likelihood, observed, prior_samples,
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

    res = result
    if log_likelihood is None:
        res = result.thin(loglik_draws(pb.data.size, result.chain.nwalkers))
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
    tree = _tree(res, posterior_predictive, log_likelihood, observed,
                     PRIOR_DRAWS if prior_samples is None else prior_samples,
                     obs_dim=obs_dim, obs_coords=obs_coords, var_name=var_name,
                     prior_seed=prior_seed)
    if ppc_draws is not None:
        # Label the replicated draws with the posterior draws they were made from.
        node = tree["posterior_predictive"]
        node.dataset = node.to_dataset(inherit=False).assign_coords(draw=ppc_draws)
    return tree


def _tree(
    result: Any,
    posterior_predictive: Any,
    log_likelihood: Any,
    observed: Any,
    prior_samples: int | np.ndarray | None,
    *,
    obs_dim: str,
    obs_coords: Any,
    var_name: str,
    prior_seed: int | None,
) -> Any:
    """Build the tree from the given groups (:func:`to_tree` without a problem)."""
    import arviz  # deferred: importing ArviZ takes ~2 s

    c = result.chain
    theta = np.swapaxes(result.theta_samples(), 0, 1)  # (walker=chain, step=draw, ndim)
    u = np.swapaxes(c.samples, 0, 1)
    groups: dict[str, dict[str, np.ndarray]] = {
        "posterior": {
            **{n: theta[..., j] for j, n in enumerate(result.names)},
            **{n: np.swapaxes(a, 0, 1) for n, a in result.derived.items()},
        },
        "unconstrained_posterior": {n: u[..., j] for j, n in enumerate(result.names)},
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
            ps = result.priors.sample(rng, int(prior_samples))
        else:
            ps = np.asarray(prior_samples, dtype=float)
        if ps.ndim != 2 or ps.shape[1] != c.ndim:
            raise ResultError(f"prior_samples must be (n, {c.ndim}), got {ps.shape}")
        groups["prior"] = {n: ps[None, :, j] for j, n in enumerate(result.names)}

    attrs = {
        "/": {
            "model": result.model,
            "parameters": _dumps(list(result.names)),
            "priors": _dumps(result.priors.to_dict()),
            "settings": _dumps(dict(result.settings)),
            "provenance": _dumps(dict(result.provenance)),
            "chain": _dumps(_chain_meta(c)),
            "map_u": _dumps(None if result.map_u is None else result.map_u),
            "mesh": _dumps(plain_mapping(result.mesh)),
            "adequacy": _dumps(plain_mapping(result.adequacy)),
        }
    }
    if result.signal_unit is not None:
        attrs["/"]["signal_unit"] = result.signal_unit
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
        ds = ds.assign({v: ds[v].assign_attrs(_variable_attrs(result, key, str(v)))
                        for v in ds.data_vars})
        if obs_dim in ds.coords:
            ds = ds.assign_coords({obs_dim: ds[obs_dim].assign_attrs(
                units="s" if obs_dim == "time" else "1",
                long_name="time of the sample" if obs_dim == "time" else "sample index")})
        node.dataset = ds
    return tree


def _variable_attrs(result: Any, group: str, name: str) -> dict[str, str]:
    """``units`` and ``long_name`` of one variable of the tree (empty if unknown)."""
    sig = result.signal_unit
    if group == "log_likelihood":
        return {"units": _NAT, "long_name": "pointwise log-likelihood"
                + (" (conditional on the previous sample)" if "rho" in result.names else "")}
    if group == "sample_stats":
        return {"units": _NAT, "long_name": "log posterior density in the sampling space u "
                "(unnormalised, Jacobian included)"} if name == "lp" else {}
    if group in ("posterior_predictive", "observed_data"):
        what = ("replicated signal: model plus a draw of the fitted noise"
                if group == "posterior_predictive" else "measured signal")
        return {"long_name": what} if sig is None else {"units": sig, "long_name": what}
    unit, meaning = parameter_units(name, sig, default=("", ""))
    if group == "unconstrained_posterior" and unit not in ("", SIGNAL):
        unit, meaning = _sampling_space_attrs(result.priors[name], name, unit)
    if unit in ("", SIGNAL):
        return {"long_name": meaning} if meaning else {}
    return {"units": unit, "long_name": meaning}


def save(result: Any, outdir: str | Path, *, idata: Any = None,
         summary_from: Any = None, **idata_kwargs: Any) -> dict[str, Path]:
    """Write ``posterior.nc`` and ``summary.json`` of ``result`` into ``outdir``.

    Parameters and returns: :meth:`bayesbeam.inference.results.FitResult.save`, which
    calls this with the result as ``result``.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    if idata is None:
        idata = to_tree(result, **idata_kwargs)
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
    text = json.dumps((summary_from or result).to_json_dict(), default=json_default,
                      allow_nan=False, indent=2)
    write_text_atomic(js, text + "\n")
    return {"netcdf": nc, "summary": js}


def fields_from_tree(idata: Any) -> dict[str, Any]:
    """Return the fields of the result a tree made by :func:`to_tree` holds.

    Parameters
    ----------
    idata : xarray.DataTree

    Returns
    -------
    dict
        Keyword arguments of :class:`~bayesbeam.inference.results.FitResult`.

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
    return dict(
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


def read_tree(path: str | Path) -> Any:
    """Read the tree that :func:`save` wrote (its directory or ``posterior.nc``).

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    xarray.DataTree
    """
    import arviz

    path = Path(path)
    if path.is_dir():
        path = path / "posterior.nc"
    if not path.is_file():
        raise ResultError(f"no result file at {path}; expected FitResult.save output")
    _require_h5netcdf()
    return arviz.from_netcdf(path, engine="h5netcdf")


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
