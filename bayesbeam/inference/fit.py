"""Bayesian calibration of one model on one trial: data-driven start, MAP, emcee posterior.

The optimiser starts from the data (physics.md §5: the source's Nelder–Mead stayed near
its initial guesses): E from the first spectral peak, the damping scale from the decay
of the band-passed envelope (:func:`bayesbeam.trials.modal_id.first_mode_decay_rate`), and
the initial-condition amplitudes and offset by linear
least squares (the signal is linear in them). A coarse E scan, then L-BFGS-B in the
sampling space from several starts, gives the MAP; the walkers start in a ball shaped by
the Laplace covariance there. Before sampling, the mesh is refined until the MAP's
prediction no longer depends on it (:mod:`bayesbeam.inference.mesh`); after, the model's
adequacy is checked against the data's own noise (:mod:`bayesbeam.inference.adequacy`).
With two or more damping laws the ensemble moves in
:class:`SamplerCoordinates` (log total first-mode damping and log ratios of the laws'
shares), where the damping ridge is straight; results are reported in the sampling
space ``u`` of :mod:`bayesbeam.stats.priors` as usual.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam.inference.adequacy import assess
from bayesbeam.inference.coordinates import (
    PREBURN_STEPS,
    SamplerCoordinates,
    sample_in_coordinates,
)
from bayesbeam.inference.map_cache import MapCache, fingerprint
from bayesbeam.inference.mesh import converge_mesh, on_mesh
from bayesbeam.inference.optimum import best_map, chain_map, diagonal_sd, local_map
from bayesbeam.inference.parallel import check_helpers
from bayesbeam.inference.problem import Problem, amplitude_names, record_f1
from bayesbeam.inference.results import FitResult, make_provenance
from bayesbeam.inference.settings import FIT_DEFAULTS, walker_count
from bayesbeam.inference.starts import data_features, neutral_value, physics_starts
from bayesbeam.physics.models import NONLINEAR, Model, parse_model
from bayesbeam.physics.propagate import single_blas_thread
from bayesbeam.stats.moves import named_moves
from bayesbeam.stats.numdiff import fd_hessian
from bayesbeam.stats.sampling import Chain, init_walkers
from bayesbeam.trials.modal_id import first_mode_decay_rate
from bayesbeam.trials.trial import Trial

__all__ = [
    "FitError",
    "clip_to_prior",
    "find_map",
    "fit",
    "laplace_covariance",
    "walker_scale",
    "profile_linear",
    "scan_E",
]


class FitError(ValueError):
    """A fit could not be set up or started."""


def _linear_names(problem: Problem) -> list[str]:
    return amplitude_names(problem.names) + (["offset"] if "offset" in problem.names else [])


def _nonlinear_columns(problem: Problem) -> list[int]:
    """Columns of the parameters that make the signal nonlinear in the amplitudes."""
    return [problem.names.index(p) for part in problem.model.nonlinear
            for p in NONLINEAR[part] if p in problem.names]


def profile_linear(problem: Problem, X: np.ndarray, *, refine: bool = True) -> np.ndarray:
    """Set the linear parameters of each row to their least-squares values.

    The initial-condition amplitudes (``w0``, ``p0``, ``A*``, ``B*``) and ``offset``
    enter the response of a linear model linearly, so for fixed other parameters they
    are profiled out exactly by one least-squares solve per row on the unit-amplitude
    basis responses.

    A model with an amplitude-dependent part (``drag``, ``friction``,
    ``amplitude_stiffness``, ``sensor_quadratic``:
    :data:`bayesbeam.physics.models.NONLINEAR`) is not linear in
    its amplitudes: a unit-amplitude basis response there is the motion of a mode a
    metre or more in size, damped by drag as such, and a least-squares fit to those
    bases gives nonsense (measured on a 50 cm aluminium record: residual RMS 1e14 m/s²
    at a drag of 0.13 kg/m²). There the amplitudes are first solved on the linear part
    (those parameters at zero: the same modes, frequencies and linear decay, which is
    where the amplitude-dependent forces are small corrections, physics.md §3), then
    refined by Gauss–Newton steps on the full model (:func:`_gauss_newton_linear`).

    Parameters
    ----------
    problem : Problem
        The calibration problem.
    X : ndarray, shape (k, ndim)
        Parameter sets in physical units.
    refine : bool
        Run the Gauss–Newton refinement for a nonlinear model (costs about
        ``3 (n_amplitudes + 1)`` forward runs per row); False keeps the linear-part
        solution (for the E scan's grids, where only the best row matters).

    Returns
    -------
    ndarray, shape (k, ndim)
        Copy of ``X`` with the linear parameters replaced (rows whose basis response is
        invalid are left unchanged).
    """
    lin = _linear_names(problem)
    if not lin:
        return X
    X = np.array(X, dtype=float, copy=True)
    k = X.shape[0]
    nonlinear = _nonlinear_columns(problem)
    base = X.copy()
    base[:, nonlinear] = 0.0  # the linear part: exactly linear in the amplitudes
    basis = []
    for name in lin:
        Xb = base.copy()
        for other in lin:
            Xb[:, problem.names.index(other)] = 0.0
        Xb[:, problem.names.index(name)] = 1.0
        if name == "offset":
            basis.append(np.ones((k, problem.data.size)))
            continue
        res = problem.predict(Xb)
        y = res.y.copy()
        y[~res.valid] = np.nan  # offset is zero in Xb, so y is the pure basis response
        basis.append(y)
    Bm = np.stack(basis, axis=-1)  # (k, T, nlin)
    for i in range(k):
        if not np.all(np.isfinite(Bm[i])):
            continue
        coef, *_ = np.linalg.lstsq(Bm[i], problem.data, rcond=None)
        for name, c in zip(lin, coef, strict=True):
            X[i, problem.names.index(name)] = c
    if nonlinear and refine:
        X = _gauss_newton_linear(problem, X, lin)
    return X


def _gauss_newton_linear(problem: Problem, X: np.ndarray, lin: list[str],
                         iterations: int = 4) -> np.ndarray:
    """Refine the amplitudes and offset of a nonlinear model by Gauss–Newton steps.

    The Jacobian of the signal in the amplitudes is a forward difference (step 1e-6 of
    the row's largest amplitude; the signal is smooth in them), the offset's column is
    exactly ones. A step is kept only where it lowers the sum of squared residuals,
    otherwise halved once; a row stops when its relative gain falls below 1e-9.

    Parameters
    ----------
    problem : Problem
    X : ndarray, shape (k, ndim)
        Physical sets with their amplitudes solved on the linear part.
    lin : list of str
        The linear parameters' names (amplitudes, then ``offset`` if present).
    iterations : int
        Most Gauss–Newton steps.

    Returns
    -------
    ndarray, shape (k, ndim)
    """
    cols = [problem.names.index(n) for n in lin]
    amp = [j for j, n in zip(cols, lin, strict=True) if n != "offset"]
    order = amp + [j for j in cols if j not in amp]  # amplitudes, then the offset
    T = problem.data.size

    def sse(Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        res = problem.predict(Z)
        r = problem.data[None, :] - res.y
        return np.where(res.valid, np.sum(r * r, axis=1), np.inf), r

    f0, r0 = sse(X)
    live = np.isfinite(f0)
    for _ in range(iterations):
        if not np.any(live):
            break
        rows = np.flatnonzero(live)
        scale = np.max(np.abs(X[np.ix_(rows, amp)]), axis=1)
        h = 1e-6 * np.where(scale > 0, scale, 1.0)  # (r,)
        P = np.repeat(X[rows], len(amp), axis=0)
        for m, j in enumerate(amp):
            P[m :: len(amp), j] += h
        res = problem.predict(P)
        dY = res.y.reshape(rows.size, len(amp), T)
        ok_rows = res.valid.reshape(rows.size, len(amp)).all(axis=1)
        for q, i in enumerate(rows):
            if not ok_rows[q]:
                live[i] = False
                continue
            y0 = problem.data - r0[i]
            J = (dY[q] - y0[None, :]).T / h[q]  # (T, n_amp)
            if len(order) > len(amp):
                J = np.column_stack([J, np.ones(T)])  # the offset
            step, *_ = np.linalg.lstsq(J, r0[i], rcond=None)
            for frac in (1.0, 0.5):
                Z = X[i : i + 1].copy()
                Z[0, order] += frac * step
                fz, rz = sse(Z)
                if fz[0] < f0[i]:
                    gain = (f0[i] - fz[0]) / f0[i]
                    X[i], f0[i], r0[i] = Z[0], fz[0], rz[0]
                    live[i] = gain > 1e-9
                    break
            else:
                live[i] = False
    return X


def clip_to_prior(problem: Problem, X: np.ndarray) -> np.ndarray:
    """Clip parameter sets into the prior support, 1e-6 of its width inside the bounds.

    Parameters
    ----------
    problem : Problem
        The calibration problem.
    X : ndarray, shape (k, ndim)
        Parameter sets in physical units.

    Returns
    -------
    ndarray, shape (k, ndim)
        Clipped copy (unbounded sides are left as they are).
    """
    lo, hi = problem.priors.bounds.T
    span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    return np.clip(X, lo + 1e-6 * span, hi - 1e-6 * span)


def _start_points(problem: Problem, rng: np.random.Generator, n_starts: int) -> np.ndarray:
    """Data-driven starting points in physical units, shape (n_starts, ndim)."""
    trial, beam = problem.trial, problem.trial.beam
    names = problem.names
    pri = problem.priors
    f1 = record_f1(trial)
    E0 = float(np.sqrt(np.prod(pri["E"].bounds)))  # prior centre = reference modulus
    w1 = 2 * np.pi * f1
    zeta = first_mode_decay_rate(trial.times, trial.values, f1) / w1
    laws = problem.model.laws
    X = np.empty((n_starts, len(names)))
    for i in range(n_starts):
        # Share the measured damping among the laws at random (Dirichlet), first start even.
        share = np.full(len(laws), 1.0 / len(laws)) if i == 0 else rng.dirichlet(np.ones(len(laws)))
        z = dict(zip(laws, np.maximum(share, 0.05) * zeta, strict=True))
        for j, n in enumerate(names):
            if n == "E":
                X[i, j] = E0
            elif n == "gamma":
                X[i, j] = 2 * beam.rhoA * w1 * z["viscous"]
            elif n == "c_d":
                X[i, j] = 2 * E0 * z["kv"] / w1
            elif n == "eta":
                X[i, j] = 2 * E0 * beam.I * z["sh"] / w1
            elif n == "b":
                X[i, j] = beam.length * (0.05 if i == 0 else 10 ** rng.uniform(-2.5, 0))
            elif n in ("tip_mass", "added_mass"):
                X[i, j] = 0.02 * beam.beam_mass * (1 if i == 0 else 10 ** rng.uniform(-1, 1))
            elif n == "added_mass_position":
                X[i, j] = beam.length * (0.8 if i == 0 else rng.uniform(0.3, 1.0))
            elif n == "root_spring":
                k_ref = 100 * E0 * beam.I / beam.length  # κ = k L/(E I) = 100: a stiff clamp
                X[i, j] = k_ref * (1 if i == 0 else 10 ** rng.uniform(-1, 1))
            elif n == "stiffness_gradient":
                X[i, j] = 0.0 if i == 0 else rng.uniform(-0.3, 0.3)
            elif n == "rho":
                X[i, j] = 0.5
            else:  # amplitudes, offset, sigma: set below
                X[i, j] = 0.0
    X[:, names.index("sigma")] = np.std(trial.values)
    return clip_to_prior(problem, X)


def scan_E(problem: Problem, X: np.ndarray, n_grid: int = 96) -> np.ndarray:
    """Refine E of each start by a profile-likelihood scan over ±15 %.

    The likelihood is highly multimodal in E (a phase error accumulates over the
    record), so a local optimiser must start within a fraction of a period. Each row is
    scanned on a coarse (±15 %) then a fine (±1.5 %) log grid of ``n_grid`` points, with
    the linear parameters profiled out and ``sigma`` set to the RMS residual.

    Parameters
    ----------
    problem : Problem
        The calibration problem.
    X : ndarray, shape (k, ndim)
        Start points in physical units.
    n_grid : int
        Grid points per scan.

    Returns
    -------
    ndarray, shape (k, ndim)
        Refined start points, inside the prior support.
    """
    j = problem.names.index("E")
    s = problem.names.index("sigma")
    out = X.copy()
    for i in range(X.shape[0]):
        for width in (0.15, 0.015):
            # Each pass is centred on the best E so far (the fine pass on the coarse one's).
            grid = out[i, j] * np.exp(np.linspace(-width, width, n_grid))
            Xg = np.repeat(out[i : i + 1], n_grid, axis=0)
            Xg[:, j] = grid
            Xg = profile_linear(problem, clip_to_prior(problem, Xg), refine=False)
            res = problem.predict(Xg)
            sse = np.where(res.valid, np.sum((problem.data - res.y) ** 2, axis=1), np.inf)
            best = int(np.argmin(sse))
            out[i] = Xg[best]
            out[i, s] = np.sqrt(sse[best] / problem.data.size)
        if _nonlinear_columns(problem):  # the grid used the linear part's amplitudes
            out[i] = profile_linear(problem, out[i : i + 1])[0]
            res = problem.predict(out[i : i + 1])
            if res.valid[0]:
                out[i, s] = np.sqrt(np.mean((problem.data - res.y[0]) ** 2))
    return clip_to_prior(problem, out)


def laplace_covariance(problem: Problem, u: np.ndarray, h: float = 1e-4) -> np.ndarray | None:
    """Inverse of the negative Hessian of log_prob at ``u`` (central differences, one batch).

    The Hessian is :func:`~bayesbeam.stats.numdiff.fd_hessian` with the four-point
    ``"corners"`` stencil on every entry.

    Parameters
    ----------
    problem : Problem
    u : ndarray, shape (ndim,)
    h : float
        Step in sampling-space units.

    Returns
    -------
    ndarray, shape (ndim, ndim) or None
        None when the Hessian is not negative definite there, or a stencil point lies
        outside the prior support.
    """
    # Every stencil value enters H (or is f0), so a point that left the prior support
    # (MAP on a bound) shows as a non-finite H or f0.
    f0, _, H = fd_hessian(problem.log_prob, u, h, stencil="corners")
    if not (np.isfinite(f0) and np.all(np.isfinite(H))):
        return None
    try:
        L = np.linalg.cholesky(-H)
    except np.linalg.LinAlgError:
        return None
    Li = np.linalg.inv(L)
    return Li.T @ Li


def walker_scale(problem: Problem, u: np.ndarray, fraction: float = 0.1) -> np.ndarray:
    """Per-coordinate sd of the initial walker ball around the MAP ``u``.

    ``fraction`` of the Laplace sd (:func:`laplace_covariance`); where the Laplace
    covariance fails, of the conditional sd from the diagonal curvature
    (:func:`diagonal_sd`); 1e-3 where neither is defined. A fixed ball of 1e-3 would
    start the walkers a thousand sd away in a parameter known to ppm (E) and strand them.

    Parameters
    ----------
    problem : Problem
    u : ndarray, shape (ndim,)
        The MAP in the sampling space.
    fraction : float
        Ball size in units of the posterior sd.

    Returns
    -------
    ndarray, shape (ndim,)
        Clipped to [1e-8, 0.5].
    """
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # -inf stencil points on a bound
        cov = laplace_covariance(problem, u)
        sd = np.sqrt(np.diag(cov)) if cov is not None else diagonal_sd(problem.log_prob, u)
    scale = np.where(np.isfinite(sd), fraction * sd, 1e-3)
    return np.clip(scale, 1e-8, 0.5)


def _physics_rows(problem: Problem) -> np.ndarray:
    """Physics-based starts for a model with structural or amplitude-dependent parts.

    Returns
    -------
    ndarray, shape (k, ndim)
        Physical units, inside the prior support; k = 0 for other models.
    """
    model = problem.model
    if not (model.structural or model.nonlinear):
        return np.empty((0, problem.ndim))
    neutral = {n: neutral_value(problem, n) for n in problem.names}
    rows = physics_starts(problem, data_features(problem.trial), {}, neutral)
    return clip_to_prior(problem, np.array(rows, dtype=float).reshape(-1, problem.ndim))


def find_map(
    problem: Problem, *, rng: np.random.Generator, n_starts: int = 4, maxiter: int = 300
) -> tuple[np.ndarray, float]:
    """Maximum a posteriori point in the sampling space.

    Parameters
    ----------
    problem : Problem
    rng : numpy.random.Generator
    n_starts : int
        Data-driven starts (the first shares damping evenly among the laws, the others
        at random), each refined by an E scan and the scaled L-BFGS-B of
        :func:`~bayesbeam.inference.optimum.local_map`; the best is polished by
        :func:`~bayesbeam.inference.optimum.newton_polish`. Models with a structural or
        amplitude-dependent part get the physics-based starts of
        :func:`bayesbeam.inference.starts.physics_starts` too (their posteriors have
        modes besides E's: e.g. a point mass along the curve of equal f2/f1).
    maxiter : int

    Returns
    -------
    u_map : ndarray, shape (ndim,)
    log_prob_map : float
    """
    X = np.vstack([_start_points(problem, rng, n_starts), _physics_rows(problem)])
    X = scan_E(problem, X)
    U = problem.priors.to_u(X)
    best_u, best_v = best_map(problem, U, maxiter=maxiter)
    if best_u is None:
        raise FitError(
            "no starting point with a finite posterior density was found; check the trial's "
            "units and the priors (bayesbeam fit --priors)"
        )
    return best_u, best_v


_SAMPLER_OPTIONS = ("n_tau", "tau_rtol", "check_every", "burn_in_taus", "thin",
                    "checkpoint_seconds", "moves", "helpers")


def _sampler_options(options: Mapping[str, Any] | None) -> dict[str, Any]:
    opts = dict(options or {})
    bad = sorted(set(opts) - set(_SAMPLER_OPTIONS))
    if bad:
        raise FitError(f"unknown sampler_options {bad}; allowed: {list(_SAMPLER_OPTIONS)}")
    try:  # checked here too, before the expensive MAP search
        check_helpers(opts.get("helpers", 0))
    except ValueError as exc:
        raise FitError(f"sampler_options: {exc}") from None
    if "moves" in opts:  # checked here, before the expensive MAP search
        try:
            named_moves(opts["moves"])
        except ValueError as exc:
            raise FitError(f"sampler_options: {exc}") from None
    return opts


def checkpoint_path(outdir: str | Path | None, resume: bool) -> Path | None:
    """Return the sampler checkpoint ``OUTDIR/chain.h5`` (made ready), or None without a folder.

    Parameters
    ----------
    outdir : path or None
    resume : bool
        False: an old checkpoint there is deleted (a new run starts).

    Returns
    -------
    pathlib.Path or None
    """
    if outdir is None:
        return None
    Path(outdir).mkdir(parents=True, exist_ok=True)
    backend = Path(outdir) / "chain.h5"
    if backend.exists() and not resume:
        backend.unlink()
    return backend


@single_blas_thread
def fit(
    trial: Trial,
    model: str | Model,
    *,
    seed: int = 0,
    priors: Mapping[str, Any] | None = None,
    n_elements: int = FIT_DEFAULTS.n_elements,
    refine_mesh: bool = FIT_DEFAULTS.refine_mesh,
    initial: str = FIT_DEFAULTS.initial,
    nwalkers: int | None = FIT_DEFAULTS.nwalkers,
    target_ess: float = FIT_DEFAULTS.target_ess,
    max_steps: int = FIT_DEFAULTS.max_steps,
    min_steps: int = FIT_DEFAULTS.min_steps,
    outdir: str | Path | None = None,
    resume: bool = False,
    progress: bool | None = None,
    problem: Problem | None = None,
    sampler_options: Mapping[str, Any] | None = None,
) -> FitResult:
    """Sample the posterior of one model on one trial.

    The trial is taken as given: the sanity checks of the command line (an implausible
    beam, a record without a free decay, stamps in ms) are not run here. On a record
    from elsewhere call :func:`bayesbeam.trials.checks.check_trial` first; afterwards
    ``adequacy`` flags a posterior piled on a prior bound and a σ of the signal's size.

    Parameters
    ----------
    trial : Trial
    model : str or Model
        e.g. ``'viscous+kv'``, ``'viscous+sh+ar1_noise'``.
    seed : int
        Seed of every random choice (starts, walkers, emcee).
    priors : mapping, optional
        Overrides of :func:`bayesbeam.inference.problem.default_priors`.
    n_elements, refine_mesh, initial, nwalkers, target_ess, max_steps, min_steps : optional
        Starting (coarsest) mesh, whether to refine it, initial-condition kind, walkers,
        convergence target and step budget: the fields of
        :class:`bayesbeam.inference.settings.FitSettings`, whose defaults
        (:data:`~bayesbeam.inference.settings.FIT_DEFAULTS`) these keywords take
        (see also :func:`bayesbeam.stats.sampling.run_emcee`).
    outdir : path, optional
        Where the HDF5 checkpoint ``chain.h5`` is kept (and results saved by the CLI).
    resume : bool
        Continue from the checkpoint in ``outdir``.
    progress : bool or None
        Progress line on stderr (None: only on a terminal).
    problem : Problem, optional
        A ready problem (then ``trial``, ``model``, ``priors``, ``n_elements`` and
        ``initial`` must match it).
    sampler_options : mapping, optional
        Further keyword arguments of :func:`bayesbeam.stats.sampling.run_emcee`
        (``n_tau``, ``tau_rtol``, ``check_every``, ``burn_in_taus``, ``thin``,
        ``checkpoint_seconds``), e.g. a cheaper stopping rule for batch studies, and
        ``moves``: the proposal mixture, a name of
        :data:`~bayesbeam.stats.moves.MOVE_SETS` (default ``"de"``), and ``helpers``:
        processes that share each batch of the sampler with this one (default 0; see
        :class:`~bayesbeam.inference.parallel.ParallelLogProb`: worth it on whole
        records, where a batch takes tens of ms).

    Returns
    -------
    FitResult
        With ``derived`` quantities (``a`` for spatial hysteresis), MAP, settings,
        provenance (package version, data SHA-256, model, priors, seed), the ``mesh``
        record (the mesh is refined from ``n_elements`` until the MAP's prediction is
        converged, :func:`~bayesbeam.inference.mesh.converge_mesh`; ``settings
        ["n_elements"]`` is the final mesh) and the ``adequacy`` checks
        (:func:`~bayesbeam.inference.adequacy.assess`).
    """
    t_start = time.perf_counter()
    sampler_kw = _sampler_options(sampler_options)  # fail before the expensive MAP
    model = parse_model(model)
    if problem is None:
        problem = Problem(trial, model, priors, n_elements=n_elements, initial=initial)
    rng = np.random.default_rng(seed)
    show = progress if progress is not None else sys.stderr.isatty()
    say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if show else None
    if say is not None:
        say(f"{model.name}: MAP search ({problem.ndim} parameters, {trial.times.size} "
            "samples)...")
    cache = MapCache(outdir, fingerprint({
        "model": model.name, "data_sha256": trial.sha256, "seed": seed,
        "n_elements": problem.n_elements, "refine_mesh": bool(refine_mesh),
        "initial": problem.initial,
        "priors": {n: problem.priors[n].to_dict() for n in problem.names},
    }), resume=resume, say=say)

    def search() -> tuple[np.ndarray, float, dict[str, Any]]:
        t_map = time.perf_counter()
        u, lp = find_map(problem, rng=rng)
        if say is not None:
            say(f"{model.name}: MAP found in {time.perf_counter() - t_map:.1f} s; mesh check")
        _, u, lp, mesh = converge_mesh(problem, u, lp, local_map, refine=refine_mesh,
                                       progress=say)
        return u, lp, mesh

    u_map, lp_map, mesh, recalled = cache.recall(
        "map", problem.ndim, lambda u, m: float(on_mesh(problem, m).log_prob(u[None])[0]),
        search, rng)
    problem = on_mesh(problem, mesh)
    if recalled and say is not None:
        say(f"{model.name}: MAP and mesh from {cache.path} (resumed run)")
    ndim = problem.ndim
    nwalkers = walker_count(nwalkers, ndim)
    scale = walker_scale(problem, u_map)
    u0 = init_walkers(problem.log_prob, u_map, nwalkers, rng=rng, scale=scale)
    coords = SamplerCoordinates(problem, at=u_map)  # the structure's scales at the MAP
    chain: Chain = sample_in_coordinates(
        problem.log_prob,
        coords,
        u0,
        seed=seed,
        max_steps=max_steps,
        min_steps=min_steps,
        target_ess=target_ess,
        backend_path=checkpoint_path(outdir, resume),
        resume=resume,
        progress=progress,
        names=problem.names,
        preburn=PREBURN_STEPS,
        label=f"fit {problem.model.name}: emcee",
        **sampler_kw,
    )
    samples = chain.samples
    # The chains may have found a higher optimum than the search's (report the higher).
    lp_search = lp_map
    u_map, lp_map = chain_map(problem, samples, chain.log_prob, u_map, lp_map)
    X = problem.theta(samples.reshape(-1, ndim))
    derived = {k: v.reshape(samples.shape[:2]) for k, v in problem.derived(X).items()}
    settings = {
        "n_elements": problem.n_elements,
        "refine_mesh": bool(refine_mesh),
        "initial": initial,
        "nwalkers": nwalkers,
        "target_ess": target_ess,
        "max_steps": max_steps,
        "sampler_options": dict(sampler_options or {}),
        "seed": seed,
        "n_samples_data": int(trial.times.size),
        "log_prob_map": lp_map,
        "log_prob_map_search": lp_search,
        "total_seconds": time.perf_counter() - t_start,
        "noise": "ar1" if "rho" in problem.names else "iid",
        "sampler_coordinates": coords.describe(),
    }
    provenance = make_provenance(
        {
            "trial": trial.name,
            "data_sha256": trial.sha256,
            "data_source": dict(trial.source),
            "model": model.name,
            "eta_definition": "eta = a * s1(b), s1 = first-mode S(b) damping over KV per c_d*I "
            "(bayesbeam.inference.problem; a is stored as a derived quantity)",
        }
    )
    result = FitResult(
        model=model.name,
        chain=chain,
        priors=problem.priors,
        map_u=u_map,
        settings=settings,
        provenance=provenance,
        derived=derived,
        mesh=mesh,
        problem=problem,  # the complete ArviZ tree (log-likelihood, predictive) needs it
    )
    # Its own stream: the checks never change the chain's random numbers.
    if say is not None:
        say(f"{model.name}: sampled in {chain.seconds:.1f} s; adequacy checks")
    adequacy = assess(problem, result, rng=np.random.default_rng([seed, 1]))
    if show and not adequacy["ok"]:
        print(f"warning: {adequacy['summary']}", file=sys.stderr, flush=True)
    return dataclasses.replace(result, adequacy=adequacy)
