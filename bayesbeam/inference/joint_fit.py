"""Joint Bayesian calibration of one model on several trials (:class:`JointProblem`).

Steps: each trial's own MAP and mesh check (:func:`bayesbeam.inference.fit.find_map`,
:func:`~bayesbeam.inference.mesh.converge_mesh`; the finest converged mesh serves every
trial); the joint MAP from those points (:meth:`JointProblem.joint_theta`, L-BFGS-B);
emcee in the centred coordinates of the pooled parameters
(:class:`~bayesbeam.inference.joint.PoolCoordinates`), with a walk of each pooled spread at
fixed non-centred values beside the ensemble's moves
(:class:`~bayesbeam.stats.moves.ReparamWalkMove`), until the ESS target; the
marginalised sigma and amplitudes drawn exactly for the kept draws; per trial, a
:class:`~bayesbeam.inference.results.FitResult` of its own parameters (completed draws) and
the adequacy checks of :func:`~bayesbeam.inference.adequacy.assess`: a joint fit must say
of every record whether the model reproduces it to its noise.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import finite_json
from bayesbeam.inference.adequacy import assess
from bayesbeam.inference.coordinates import (
    PREBURN_STEPS,
    ClampCoordinates,
    SamplerCoordinates,
    sample_in_coordinates,
)
from bayesbeam.inference.fit import _sampler_options, checkpoint_path, find_map, walker_scale
from bayesbeam.inference.joint import TIP_DISTANCE, JointProblem, PoolCoordinates
from bayesbeam.inference.map_cache import MapCache, fingerprint
from bayesbeam.inference.mesh import converge_mesh, on_mesh
from bayesbeam.inference.optimum import chain_map, escape_bounds, local_map
from bayesbeam.inference.results import FitResult, make_provenance
from bayesbeam.inference.settings import FIT_DEFAULTS, walker_count
from bayesbeam.physics.models import Model, parse_model
from bayesbeam.physics.propagate import single_blas_thread
from bayesbeam.stats.convergence import autocorr_time, ess_rhat
from bayesbeam.stats.moves import ReparamWalkMove
from bayesbeam.stats.sampling import Chain, init_walkers
from bayesbeam.trials.trial import Trial

__all__ = ["JointFit", "fit_joint"]


def _json(obj: Any) -> str:
    import json

    return json.dumps(obj, default=str)

#: Posterior draws kept for the completed per-trial posteriors (sigma and amplitudes
#: drawn given each kept draw) and their reports.
MAX_DRAWS = 2000
#: Share of the sampler's steps that walk the pooled spreads at fixed non-centred values
#: (:class:`~bayesbeam.stats.moves.ReparamWalkMove`); the named mixture has the rest.
SPREAD_MOVE_WEIGHT = 0.2


@dataclasses.dataclass(frozen=True)
class JointFit:
    """Outcome of a joint fit (immutable).

    Attributes
    ----------
    result : FitResult
        The joint posterior in the joint sampling space (shared, population, per-trial
        names): the whole post-burn-in chain, for the evidence.
    trials : tuple of FitResult
        Per trial, its own parameters (its Problem's names and priors, the problem
        attached; pooled values and the marginalised sigma and amplitudes completed)
        at the draws of ``result.thin(MAX_DRAWS)``, with its adequacy checks.
    labels : tuple of str
        Trial labels, the ``TRIAL`` of the names.
    problem : JointProblem
        The problem that was fitted.
    """

    result: FitResult
    trials: tuple[FitResult, ...]
    labels: tuple[str, ...]
    problem: Any = dataclasses.field(repr=False)

    @property
    def ok(self) -> bool:
        """True when the model reproduces every trial to its noise."""
        return all(r.adequacy.get("ok", False) for r in self.trials)

    def summary(self) -> dict[str, dict[str, float]]:
        """Joint posterior summary (:meth:`FitResult.summary`)."""
        return self.result.summary()

    def to_json_dict(self) -> dict[str, Any]:
        """Record for ``summary.json`` / ``--json``: the joint result plus ``trials``.

        Returns
        -------
        dict
            :meth:`FitResult.to_json_dict` of the joint result with ``joint``
            (:meth:`~bayesbeam.inference.joint.JointProblem.record`), ``adequate`` (all
            trials) and ``trials``: per label ``{"trial", "adequacy", "posterior"}``.
        """
        d = self.result.to_json_dict()
        pb = self.problem
        # Each trial's pooled values and marginalised parameters, from its completed draws
        # (and its position from the clamp where the tip distance is shared).
        mapped = ("added_mass_position",) if TIP_DISTANCE in pb.shared else ()
        for lb, view in zip(self.labels, self.trials, strict=True):
            post, units = view.summary(), view.units()
            for n in (*pb.pooled, *pb.marginalised, *mapped):
                if n not in post:  # an amplitude of a mode this trial does not hold
                    continue
                d["posterior"][f"{n}[{lb}]"] = post[n]
                d["units"][f"{n}[{lb}]"] = units[n]
        d["joint"] = pb.record()
        d["adequate"] = self.ok
        d["trials"] = {
            lb: {"trial": r.provenance.get("trial"), "adequacy": r.to_json_dict()["adequacy"],
                 "posterior": r.to_json_dict()["posterior"]}
            for lb, r in zip(self.labels, self.trials, strict=True)
        }
        return finite_json(d)

    def to_inference_data(self, *, rng: np.random.Generator | None = None) -> Any:
        """ArviZ DataTree of the joint posterior with a ``trial`` dimension.

        Groups: ``posterior`` (shared and population parameters per draw; every
        per-trial parameter, the marginalised sigma and amplitudes included, as one
        variable with dims ``(chain, draw, trial)``), ``sample_stats`` (``lp``),
        ``log_likelihood`` and ``observed_data`` (``y`` over ``obs``, the trials'
        samples concatenated; the coordinate ``obs_trial`` says whose). Units and
        long names on every posterior variable.

        Parameters
        ----------
        rng : numpy.random.Generator, optional
            For the marginalised parameters' draws of the pointwise log-likelihood
            (default: seeded by the chain's seed).

        Returns
        -------
        xarray.DataTree
        """
        import arviz  # deferred: importing ArviZ takes ~2 s

        from bayesbeam.physics.models import SIGNAL, parameter_units

        res, pb = self.result.thin(MAX_DRAWS), self.problem  # the views' draws
        rng = np.random.default_rng([res.chain.seed, 3]) if rng is None else rng
        post: dict[str, np.ndarray] = {}
        theta = np.swapaxes(res.theta_samples(), 0, 1)
        for j, n in enumerate(res.names):
            if "[" not in n:
                post[n] = theta[..., j]
        # Every trial's names (amplitudes differ where the trials' initial kinds do);
        # NaN where a trial has no such parameter.
        base = dict.fromkeys(n for p in pb.problems for n in p.names)
        thetas = [v.theta_samples() for v in self.trials]  # once per trial
        for n in base:
            if n in pb.shared:
                continue
            stack = [np.swapaxes(th[..., p.names.index(n)] if n in p.names
                                 else np.full(th.shape[:-1], np.nan), 0, 1)
                     for p, th in zip(pb.problems, thetas, strict=True)]
            post[n] = np.stack(stack, axis=-1)
        for n in next(iter(self.trials)).derived if self.trials else ():
            post[n] = np.stack([np.swapaxes(v.derived[n], 0, 1) for v in self.trials], axis=-1)
        dims = {n: ["trial"] for n, a in post.items() if a.ndim == 3}
        c = res.chain
        flat = c.samples.reshape(-1, c.ndim)
        ll = pb.log_likelihood_pointwise(flat, rng).reshape(c.nsteps, c.nwalkers, -1)
        obs = np.concatenate([p.data for p in pb.problems])
        obs_trial = np.concatenate([[lb] * p.data.size for lb, p in zip(self.labels,
                                                                         pb.problems, strict=True)])
        groups = {
            "posterior": post,
            "sample_stats": {"lp": np.swapaxes(c.log_prob, 0, 1)},
            "log_likelihood": {"y": np.swapaxes(ll, 0, 1)},
            "observed_data": {"y": obs},
        }
        dims["y"] = ["obs"]
        attrs = {"/": {"model": res.model, "joint": _json(res.settings.get("joint", {})),
                       "settings": _json(dict(res.settings)),
                       "provenance": _json(dict(res.provenance)),
                       "adequate": int(self.ok)}}
        tree = arviz.from_dict(groups, dims=dims, coords={"trial": list(self.labels),
                                                          "obs": np.arange(obs.size)},
                               attrs=attrs, check_conventions=False)
        units = {p.trial.quantity for p in pb.problems}
        sig = pb.problems[0].signal_unit if len(units) == 1 else None
        ds = tree["posterior"].to_dataset(inherit=False)
        new = {}
        for v in ds.data_vars:
            unit, meaning = parameter_units(str(v), sig, default=("", ""))
            a = {"long_name": meaning} if meaning else {}
            if unit not in ("", SIGNAL):
                a["units"] = unit
            new[v] = ds[v].assign_attrs(a)
        tree["posterior"].dataset = ds.assign(new)
        tree["log_likelihood"].dataset = tree["log_likelihood"].to_dataset(
            inherit=False).assign_coords(obs_trial=("obs", obs_trial))
        return tree

    def __str__(self) -> str:
        lines = [str(self.result)]
        for lb, r in zip(self.labels, self.trials, strict=True):
            lines.append(f"{lb}: {r.adequacy.get('summary', '')}")
        return "\n".join(lines)


class _Coordinates:
    """The sampler's coordinates of a joint fit.

    First the pooled parameters centred (:class:`~bayesbeam.inference.joint.PoolCoordinates`:
    each ``NAME_z[TRIAL]`` column then holds ``log x_i``), then each trial's damping laws,
    per trial or pooled alike, as log total first-mode damping and log ratios
    (:class:`~bayesbeam.inference.fit.SamplerCoordinates` on those ``log x`` columns, unit
    Jacobian): with one mode in band the data fix each trial's total damping and leave
    the split between laws loose, a ridge these coordinates straighten. Where E and the
    clamp spring are both shared, or both per trial, they move as log ω1² and log k
    (:class:`~bayesbeam.inference.coordinates.ClampCoordinates`, the first trial's beam
    for a shared pair): one mode in band fixes ω1 and leaves a curved ridge between the
    two. Each trial's laws then take their scales at the point's E and ω1, as in
    :class:`~bayesbeam.inference.coordinates.SamplerCoordinates`. A pair pooled, or split
    between shared and per trial, stays in ``u``.
    """

    def __init__(self, jp: JointProblem) -> None:
        self.pool = PoolCoordinates(jp)
        # The clamp maps first: each trial's laws read log E and log ω1² from its pair.
        self.clamps: list[ClampCoordinates] = []
        clamp_of: dict[str, ClampCoordinates] = {}
        pair = ("E", "root_spring")
        if not any(n in jp.pooled for n in pair) and (
                (pair[0] in jp.shared) == (pair[1] in jp.shared)):
            for label, pb in zip(jp.labels, jp.problems, strict=True):
                names = [n if n in jp.shared else f"{n}[{label}]" for n in pair]
                if not all(n in jp.names for n in names):
                    continue
                cols = tuple(jp.names.index(n) for n in names)
                same = [c for c in self.clamps if (c.iE, c.ik) == cols]
                if same:  # a shared pair: the first trial's map
                    clamp_of[label] = same[0]
                    continue
                clamp = ClampCoordinates.for_problem(pb, *cols)
                if clamp is not None:
                    self.clamps.append(clamp)
                    clamp_of[label] = clamp
        self.laws = []
        for label, pb in zip(jp.labels, jp.problems, strict=True):
            sc = SamplerCoordinates(pb)
            names = [f"{pb.names[j]}_z[{label}]" if pb.names[j] in jp.pooled
                     else f"{pb.names[j]}[{label}]" for j in sc.group]
            if sc.group.size and all(n in jp.names for n in names):
                self.laws.append(SamplerCoordinates.on_columns(
                    [jp.names.index(n) for n in names], sc.c, offset=sc.offset,
                    kinds=sc.kinds, coupled=clamp_of.get(label)))

    @property
    def identity(self) -> bool:
        """True when the sampler works in ``u`` itself."""
        return self.pool.identity and not self.laws and not self.clamps

    def describe(self) -> str:
        """One line for the settings record."""
        parts = []
        if not self.pool.identity:
            parts.append("each pooled parameter's z as centred log values")
        if self.laws:
            parts.append(f"{len(self.laws)} trial(s)' damping laws as log total first-mode "
                         "damping (FE first mode) and log ratios")
        if self.clamps:
            parts.append(f"{len(self.clamps)} E and clamp spring pair(s) as log first-mode "
                         "ω² and log root_spring")
        return "u" if not parts else "u with " + "; ".join(parts)

    def to_v(self, U: np.ndarray) -> np.ndarray:
        """Map sampling-space points to sampler coordinates, shape kept."""
        X = self.pool.to_v(U)  # pooled columns as log x; E and k untouched
        V = X.copy()  # the laws read X while they write V
        for m in self.clamps:
            V = m.to_v(V)
        for m in self.laws:
            m.laws_to_v(X, V)
        return V

    def to_u(self, V: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_v`."""
        V = np.asarray(V, dtype=float)
        X = V.copy()
        for m in self.clamps:  # disjoint columns: each reads its own v_E and log k
            X = m.to_u(X)
        for m in self.laws:
            m.laws_to_u(V, X)
        return self.pool.to_u(X)

    @property
    def free(self) -> np.ndarray:
        """Columns of ``v`` with no bound: the pooled ``z``, the laws' total and ratios, v_E."""
        cols = ([z for _, _, z in self.pool.groups] + [m.group for m in self.laws]
                + [m.free for m in self.clamps])
        return np.unique(np.concatenate(cols)) if cols else np.array([], dtype=int)

    def log_jacobian(self, V: np.ndarray) -> np.ndarray:
        """``log |∂u/∂v|``: the pool map's plus the clamp maps' (the law maps' is 1).

        The pool map's depends on the spread columns only and each clamp map's on its E
        and spring columns, which no other map moves (a pooled E or spring has no clamp
        map), so each reads its columns in ``V`` directly.
        """
        out = self.pool.log_jacobian(V)
        for m in self.clamps:
            out = out + m.log_jacobian(V)
        return out


def _view(problem: Any, samples_u: np.ndarray, log_prob: np.ndarray, joint: FitResult,
          trial: Trial, label: str) -> FitResult:
    """Return a trial's own FitResult at the joint draws (completed, in its sampling space)."""
    tau, _ = autocorr_time(samples_u, 0.0)
    ess, rhat = ess_rhat(samples_u)
    chain = dataclasses.replace(joint.chain, samples=samples_u, log_prob=log_prob,
                                names=tuple(problem.names), tau=tau, ess=ess, rhat=rhat)
    derived = {}
    if "eta" in problem.names:
        X = problem.theta(samples_u.reshape(-1, problem.ndim))
        derived = {k: v.reshape(samples_u.shape[:2]) for k, v in problem.derived(X).items()}
    prov = dict(joint.provenance)
    prov.update(trial=trial.name, data_sha256=trial.sha256, joint_label=label)
    return FitResult(model=joint.model, chain=chain, priors=problem.priors, settings=joint.settings,
                     provenance=prov, derived=derived, problem=problem)


@single_blas_thread
def fit_joint(
    trials: Sequence[Trial],
    model: str | Model,
    *,
    shared: Iterable[str] = ("E",),
    pooled: Iterable[str] = (),
    marginalise: bool | None = None,
    seed: int = 0,
    n_elements: int = FIT_DEFAULTS.n_elements,
    refine_mesh: bool = FIT_DEFAULTS.refine_mesh,
    initial: str | Sequence[str] = FIT_DEFAULTS.initial,
    nwalkers: int | None = FIT_DEFAULTS.nwalkers,
    target_ess: float = FIT_DEFAULTS.target_ess,
    max_steps: int = FIT_DEFAULTS.max_steps,
    min_steps: int = FIT_DEFAULTS.min_steps,
    outdir: str | Path | None = None,
    resume: bool = False,
    progress: bool | None = None,
    sampler_options: Mapping[str, Any] | None = None,
    priors: Mapping[str, Any] | None = None,
) -> JointFit:
    """Sample the joint posterior of one model on several trials.

    Parameters
    ----------
    trials : sequence of Trial
        The records (SI units); labels are their names (:func:`trial_labels`).
    model : str or Model
    shared, pooled, marginalise
        See :class:`~bayesbeam.inference.joint.JointProblem`.
    seed : int
        Seed of every random choice (starts, walkers, emcee, the marginalised draws).
    n_elements, refine_mesh, nwalkers, target_ess, max_steps, min_steps
        As for :func:`bayesbeam.inference.fit.fit`.
    initial : str or sequence of str
        As for :func:`bayesbeam.inference.fit.fit`, one for all trials or one per trial.
    outdir : path, optional
        Where the HDF5 checkpoint ``chain.h5`` is kept.
    resume : bool
        Continue from the checkpoint in ``outdir``.
    progress : bool or None
        Progress lines on stderr (None: only on a terminal).
    sampler_options : mapping, optional
        As for :func:`bayesbeam.inference.fit.fit`.
    priors : mapping of name -> Prior or dict, optional
        Overrides of every trial's default priors (see
        :class:`~bayesbeam.inference.joint.JointProblem`).

    Returns
    -------
    JointFit
    """
    t_start = time.perf_counter()
    sampler_kw = _sampler_options(sampler_options)
    model = parse_model(model)
    trials = list(trials)
    rng = np.random.default_rng(seed)
    show = progress if progress is not None else sys.stderr.isatty()

    def say(msg: str) -> None:
        if show:
            print(msg, file=sys.stderr, flush=True)

    # Build (and so check the names) before any expensive step.
    jp = JointProblem(trials, model, shared=shared, pooled=pooled, marginalise=marginalise,
                      n_elements=n_elements, initial=initial, priors=priors)
    say(f"joint {model.name}: {jp.marginal_note}")
    cache = MapCache(outdir, fingerprint({
        "model": model.name, "data_sha256": [t.sha256 for t in trials], "seed": seed,
        "shared": list(jp.shared), "pooled": list(jp.pooled), "marginalise": jp.marginalise,
        "n_elements": jp.n_elements, "refine_mesh": bool(refine_mesh), "initial": initial,
        "priors": {n: jp.priors[n].to_dict() for n in jp.names},
    }), resume=resume, say=say)
    starts, meshes = [], []
    for i, pb in enumerate(jp.problems):
        say(f"joint {model.name}: MAP of trial {i + 1}/{len(trials)} ({jp.labels[i]})")

        def search(pb: Any = pb) -> tuple[np.ndarray, float, dict[str, Any]]:
            u, lp = find_map(pb, rng=rng)
            _, u, lp, mesh = converge_mesh(pb, u, lp, local_map, refine=refine_mesh)
            return u, lp, mesh

        u, _, mesh, recalled = cache.recall(
            f"trial {i + 1}", pb.ndim,
            lambda u, m, pb=pb: float(on_mesh(pb, m).log_prob(u[None])[0]), search, rng)
        pb = on_mesh(pb, mesh)
        if recalled:
            say(f"joint {model.name}: ... from {cache.path} (resumed run)")
        starts.append(pb.priors.to_theta(u[None])[0])
        meshes.append(dict(mesh))
    n_el = max(int(m.get("n_elements", n_elements)) for m in meshes)
    if n_el != jp.n_elements:
        jp = JointProblem(trials, model, shared=shared, pooled=pooled, marginalise=marginalise,
                          n_elements=n_el, initial=initial, priors=priors)
    x0 = jp.joint_theta(starts)
    lo, hi = jp.priors.bounds.T
    span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    x0 = np.clip(x0, lo + 1e-6 * span, hi - 1e-6 * span)
    coords = _Coordinates(jp)
    say(f"joint {model.name}: joint MAP ({jp.ndim} parameters, {len(trials)} trials)")

    def joint_search() -> tuple[np.ndarray, float, None]:
        u, lp = local_map(jp, jp.priors.to_u(x0[None])[0], coords=coords)
        u, lp = escape_bounds(jp, u, lp, coords=coords)
        return u, lp, None

    u_map, lp_map, _, recalled = cache.recall(
        "joint", jp.ndim, lambda u, m: float(jp.log_prob(u[None])[0]), joint_search, rng)
    if recalled:
        say(f"joint {model.name}: ... from {cache.path} (resumed run)")
    if not np.isfinite(lp_map):
        from bayesbeam.inference.fit import FitError

        raise FitError("the joint MAP search found no finite posterior density; fit the "
                       "trials one by one first to see which record or prior fails")
    ndim = jp.ndim
    nwalkers = walker_count(nwalkers, ndim)
    scale = walker_scale(jp, u_map)
    u0 = init_walkers(jp.log_prob, u_map, nwalkers, rng=rng, scale=scale)
    # Pooled spreads: a walk of log s at fixed non-centred z_i beside the centred
    # ensemble (ReparamWalkMove), where a spread near zero is a funnel for the ensemble
    # (tests/stats/test_moves.py: the centred DE mixture alone does not converge there).
    spreads = [s for _, s, _ in coords.pool.groups]
    extra = ([(ReparamWalkMove(coords.to_u, coords.to_v, coords.log_jacobian, spreads),
               SPREAD_MOVE_WEIGHT)] if spreads else [])
    chain: Chain = sample_in_coordinates(
        jp.log_prob, coords, u0, seed=seed, max_steps=max_steps, min_steps=min_steps,
        extra_moves=extra,
        target_ess=target_ess, backend_path=checkpoint_path(outdir, resume), resume=resume,
        progress=progress, names=jp.names, preburn=PREBURN_STEPS,
        label=f"joint {model.name}: emcee", **sampler_kw,
    )
    # As a single fit: the chains may have found a higher optimum than the search's.
    lp_search = lp_map
    u_map, lp_map = chain_map(jp, chain.samples, chain.log_prob, u_map, lp_map)
    settings = {
        "n_elements": jp.n_elements, "refine_mesh": bool(refine_mesh),
        "initial": initial if isinstance(initial, str) else list(initial),
        "nwalkers": nwalkers, "target_ess": target_ess, "max_steps": max_steps,
        "sampler_options": dict(sampler_options or {}), "seed": seed,
        "prior_overrides": {n: jp.problems[0].priors[n].to_dict() for n in jp.overrides},
        "n_samples_data": [int(t.times.size) for t in trials],
        "log_prob_map": lp_map, "log_prob_map_search": lp_search,
        "total_seconds": time.perf_counter() - t_start,
        "noise": "ar1" if "rho" in jp.problems[0].names else "iid",
        "joint": jp.record(),
        "sampler_coordinates": coords.describe(),
        "spread_move_weight": SPREAD_MOVE_WEIGHT if spreads else 0.0,
        "mesh_per_trial": [m.get("summary", "") for m in meshes],
    }
    provenance = make_provenance({
        "trial": [t.name for t in trials],
        "data_sha256": [t.sha256 for t in trials],
        "model": model.name,
    })
    full = FitResult(model=model.name, chain=chain, priors=jp.priors, map_u=u_map,
                     settings=settings, provenance=provenance)
    # Complete the kept draws: each trial's own parameters, the marginalised drawn exactly.
    joint = full.thin(MAX_DRAWS)
    c = joint.chain
    complete = jp.complete(c.samples.reshape(-1, ndim), np.random.default_rng([seed, 2]))
    views = []
    arng = np.random.default_rng([seed, 1])
    for i, (pb, Xi) in enumerate(zip(jp.problems, complete, strict=True)):
        ok = np.all(np.isfinite(Xi), axis=1)
        if not np.all(ok):  # an invalid draw cannot be in a posterior; keep the rest
            Xi = np.where(ok[:, None], Xi, Xi[np.argmax(ok)])
        u_i = pb.priors.to_u(Xi).reshape(*c.samples.shape[:2], pb.ndim)
        view = _view(pb, u_i, c.log_prob, joint, trials[i], jp.labels[i])
        say(f"joint {model.name}: adequacy of {jp.labels[i]}")
        view = dataclasses.replace(view, adequacy=assess(pb, view, rng=arng))
        views.append(view)
    out = JointFit(result=full, trials=tuple(views), labels=jp.labels, problem=jp)
    if show and not out.ok:
        bad = [lb for lb, v in zip(jp.labels, views, strict=True) if not v.adequacy.get("ok")]
        print(f"warning: the model does not reproduce {bad} to their noise", file=sys.stderr)
    return out
