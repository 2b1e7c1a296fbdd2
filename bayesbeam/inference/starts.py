"""Physics-based start points of the MAP search, from the data's own modal estimates.

The posteriors of the structural and amplitude-dependent extensions are multimodal (a
phase error accumulates over a record, and f2/f1 alone leaves a curve of (position,
mass) pairs for a point mass), so a local optimiser needs starts near the right mode.
These come from the record itself (:mod:`bayesbeam.trials.modal_id`): f1, f2, f3 and the
decay rates of modes 1 and 2 by damped sinusoids, the decay rate and f1 against
amplitude. :func:`bayesbeam.inference.fit.find_map` adds them for models with such
parameters, and the diagnosis (:mod:`bayesbeam.diagnosis.search`) uses them in every
screen. What separates the structural causes is in :mod:`bayesbeam.diagnosis.diagnose`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import scipy.optimize as sopt

from bayesbeam.inference.problem import record_f1
from bayesbeam.stats.whiteness import autocorrelation
from bayesbeam.trials.modal_id import (
    decay_rate_vs_amplitude,
    periodogram,
    spectral_peak,
    windowed_sinusoids,
)
from bayesbeam.trials.trial import Trial

__all__ = ["data_features", "neutral_value", "physics_starts"]


def data_features(trial: Trial) -> dict[str, float]:
    """Measured f1, f2 (f3), amplitudes and decay rates of a record, for physics-based starts.

    Parameters
    ----------
    trial : Trial

    Returns
    -------
    dict
        ``f1``, ``f2``, ``f3`` (Hz), ``a1``, ``a2`` (sensor units), ``sigma1``, ``sigma2``
        (decay rates, 1/s), and where measurable ``excess``, ``excess_se``, ``rate0`` (decay
        rate against amplitude) and ``f1_slope``, ``f1_slope_se`` (Hz/m); a key is absent
        where the record does not show it.
    """
    t, y = trial.times, trial.values
    f1 = record_f1(trial)
    nyq = 0.5 / float(np.median(np.diff(t)))
    f, amp = periodogram(t, y)
    guesses = [f1]
    # The modes the preprocessing saw on the raw stamps, where it ran; else the
    # spectrum near the uniform-cantilever ratios f2/f1 = 6.267, f3/f1 = 17.55
    # (physics.md §4).
    seen = trial.meta.get("modes_seen_hz") or {}
    for k, ratio in ((2, 6.267), (3, 17.55)):
        g = seen.get(str(k)) or spectral_peak(f, amp, f1 * ratio, rel_window=0.15)
        if g is None or g > 0.8 * nyq:
            break
        guesses.append(float(g))
    est, _ = windowed_sinusoids(t, y, guesses)
    feats: dict[str, float] = {"f1": f1}
    for k, e in enumerate(est[:2], start=1):
        if e is not None:
            feats[f"f{k}"] = e.frequency
            feats[f"a{k}"] = e.amplitude
            if e.decay_rate > 0:
                feats[f"sigma{k}"] = e.decay_rate
    if len(est) > 2 and est[2] is not None and "f2" in feats:
        feats["f3"] = est[2].frequency  # places an added mass along the span
    if est[0] is None:
        feats.pop("f2", None)  # a ratio needs both
        feats.pop("f3", None)
    else:
        # Amplitude dependence of the first mode's decay (starts for drag).
        dva = decay_rate_vs_amplitude(t, y, est[0].frequency,
                                      other=[est[0].frequency * r for r in (6.267, 17.55)])
        if dva is not None and np.isfinite(dva.excess_se):
            feats.update(excess=dva.excess, excess_se=dva.excess_se, rate0=dva.rate0)
        feats.update(_frequency_slope(trial, est[0].frequency))
    return feats


def physics_starts(pb: Any, feats: Mapping[str, float], warm: Mapping[str, float],
                   neutral: Mapping[str, float]) -> list[list[float]]:
    """Physical start points from the data's modal estimates.

    A structural parameter solved for the measured f2/f1 (:func:`_root_on_ratio`), a
    point mass along the f2/f1 curve picked by f3/f1 (:func:`_added_mass_starts`), E
    for the measured f1, damping coefficients for the measured decay rates
    (:func:`_set_damping`), drag or friction for the measured ζ1
    (:func:`_amplitude_starts`), the amplitude-dependent frequency at its measured slope.

    Parameters
    ----------
    pb : Problem
    feats : mapping
        :func:`data_features` of the problem's trial.
    warm : mapping
        Values known already (a current MAP; empty for none): only the parameters it
        lacks get physics-based values.
    neutral : mapping
        Every parameter's value at which it does (almost) nothing (:func:`neutral_value`).

    Returns
    -------
    list of list of float
        Rows in the order of ``pb.names``, physical units.
    """
    names = list(pb.names)
    lin = _linear_forward(pb)
    base = {n: warm.get(n, neutral[n]) for n in names}
    # From a warm start only the parameters it lacks need physics-based values.
    new = {n for n in names if n not in warm}
    struct = [n for n in names if n in ("tip_mass", "root_spring", "stiffness_gradient")]
    variants: list[dict[str, float]] = []
    if not warm or new & {"gamma", "c_d", "eta", "b"}:
        variants.append(dict(base))
    if "f2" in feats:
        target = feats["f2"] / feats["f1"]
        for s in struct:
            if s not in new:
                continue
            v = dict(base)
            for other in struct:
                v[other] = neutral[other]
            lo, hi = pb.priors[s].bounds_u
            grid_u = np.linspace(lo, hi, 41)[1:-1]
            grid = pb.priors[s].from_u(grid_u)
            th = np.repeat(_fwd_row(pb, lin, v)[None], grid.size, axis=0)
            th[:, lin.param_names.index(s)] = grid
            om, _, _ = lin.modal_system(th)
            miss = om[:, 1] / om[:, 0] - target
            i = int(np.argmin(np.abs(miss)))
            # Refine between the bracketing grid points: 1e-3 of f2/f1 is already a
            # phase error of ~0.1 cycle per second at f2 ~ 60 Hz.
            j = i + 1 if i + 1 < grid.size and miss[i] * miss[i + 1] < 0 else i - 1
            if 0 <= j < grid.size and miss[i] * miss[j] < 0:
                v[s] = _root_on_ratio(pb, lin, v, s, grid_u[min(i, j)], grid_u[max(i, j)],
                                      target)
            else:
                v[s] = float(grid[i])
            variants.append(v)
        if "added_mass" in new:
            v = dict(base)
            for other in struct:
                v[other] = neutral[other]
            variants += _added_mass_starts(pb, lin, v, feats)
    rows = []
    for v in variants:
        th = _fwd_row(pb, lin, v)
        om, _, _ = lin.modal_system(th[None])
        E = v["E"] * (2 * np.pi * feats["f1"] / om[0, 0]) ** 2
        v["E"] = float(np.clip(E, *pb.priors["E"].bounds))
        _set_damping(pb, lin, v, feats)
        rows.append([v[n] for n in names])
    # Starts for whichever amplitude-dependent damping the candidate adds (drag and
    # friction are separate candidates; a model fitted from scratch may have both).
    amp_new = tuple(n for n in ("drag", "friction") if n in new)
    if amp_new and "a1" in feats and "sigma1" in feats:
        v0 = variants[0] if variants else base
        rows += [[v[n] for n in names]
                 for v in _amplitude_starts(pb, lin, v0, feats, amp_new)]
    if "rho" in new:
        rows.append(_noise_start(pb, variants[0] if variants else base))
    if "f1_slope" in new and "f1_slope" in feats:
        # The data's f1 against the mode-1 tip amplitude (sliding windows), and half.
        v0 = variants[0] if variants else base
        lo, hi = pb.priors["f1_slope"].bounds
        for fac in (1.0, 0.5):
            w = dict(v0)
            w["f1_slope"] = float(np.clip(fac * feats["f1_slope"], 0.99 * lo, 0.99 * hi))
            rows.append([w[n] for n in names])
    return rows

# -- many models at once (an executor) ---------------------------------------------


def neutral_value(pb: Any, name: str) -> float:
    """Return a value at which an extension's parameter does (almost) nothing.

    Parameters
    ----------
    pb : Problem
    name : str
        A sampled parameter of ``pb``.

    Returns
    -------
    float
        Physical units of the parameter.
    """
    lo, hi = pb.priors[name].bounds
    L = pb.trial.beam.length
    table = {"stiffness_gradient": 0.0, "rho": 0.01, "offset": 0.0, "b": 0.3 * L, "w0": 0.0}
    if name in table:
        return table[name]
    if name == "root_spring":
        return hi / 2.0
    if name == "sigma":
        return float(np.std(pb.data))
    if name == "E":
        return float(np.sqrt(lo * hi)) if np.isfinite(hi) else float(lo)
    if name in ("tip_mass", "added_mass"):
        return 1.001 * lo  # even 0.3 % of the beam mass shifts f1 by ~0.6 %
    if name == "added_mass_position":
        # At the clamp a point mass does exactly nothing (its node's displacement and
        # slope are held at zero), whatever its size: the candidate then nests the
        # current model. Elsewhere even the prior's smallest mass (0.1 % of the beam's)
        # shifts the frequencies by ~1e-3, a phase error of a cycle of mode 2 over a
        # whole record: 1013 nats on Al 40 cm #0 at 0.5 L.
        return float(lo)
    if np.isfinite(lo) and lo > 0:
        # Damping coefficients, drag, friction: the prior's lower end (even that is not
        # quite neutral: KV at ζ1 = 1e-6 still damps the highest FE modes visibly in an
        # acceleration record).
        return 1.001 * lo
    return float(np.clip(0.0, lo, hi))


def _linear_forward(pb: Any) -> Any:
    """Return the linear forward model of a problem (the linear part of a nonlinear one)."""
    from bayesbeam.physics.forward import Forward

    if isinstance(pb.forward, Forward):
        return pb.forward
    if isinstance(getattr(pb.forward, "linear", None), Forward):
        return pb.forward.linear  # NonlinearForward keeps its linear part
    m = pb.model
    parts = [p for p in m.parts if p not in m.nonlinear and p not in m.noise]
    return Forward(pb.trial.beam, "+".join(parts), pb.trial.times[:2],
                   n_elements=pb.n_elements, initial=pb.initial)


def _fwd_row(pb: Any, lin: Any, v: Mapping[str, float]) -> np.ndarray:
    """Forward-parameter row of the linear model from sampled values (eta → a)."""
    X = np.array([[v[n] for n in pb.names]])
    P = pb.forward_params(X)[0]
    vals = dict(zip(pb.forward.param_names, P, strict=True))
    return np.array([vals[n] for n in lin.param_names], dtype=float)


def _noise_start(pb: Any, v: Mapping[str, float]) -> list[float]:
    """Start with the AR(1) noise fitted to the residual of ``v``'s mean prediction.

    ``rho`` is the residual's lag-1 correlation and ``sigma`` its RMS (the stationary
    parameterisation of :mod:`bayesbeam.stats.likelihood`: ``sigma`` is the residuals'
    own sd): the noise model's optimum for that mean. From the current MAP with ``rho``
    at its neutral 0.01 the search ran ``rho`` onto its prior bound (0.995) and stopped
    10 300 nats short on Al 30 cm #0 (+4477 over the iid model); from this start it
    reached +14764, 8 nats below the best point the chains visited.

    Parameters
    ----------
    pb : Problem
        A problem with ``rho`` among its parameters.
    v : mapping
        Values of ``pb.names`` (SI units); ``rho`` and ``sigma`` are replaced.

    Returns
    -------
    list of float
        The start, in the order of ``pb.names``.
    """
    row = np.array([[v[n] for n in pb.names]], dtype=float)
    res = pb.predict(row)
    w = dict(v)
    if res.valid[0]:
        r = pb.data - res.y[0]
        lo, hi = pb.priors["rho"].bounds
        lag1 = float(autocorrelation(r, 1)[1])
        w["rho"] = float(np.clip(lag1, lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo)))
        w["sigma"] = float(np.sqrt(np.mean(r**2)))
    return [w[n] for n in pb.names]


def _frequency_slope(trial: Any, f1: float) -> dict[str, float]:
    """Return the data's change of f1 per m of mode-1 tip amplitude and its se (Hz/m), or {}.

    Sliding windows of four mode-1 periods (:func:`bayesbeam.trials.amplitude.
    amplitude_curves`), weighted slope (:func:`~bayesbeam.trials.amplitude_bins.
    amplitude_trend`, Hz per mm, converted here to SI). Empty for a record shorter than
    three windows or without a mode-1 peak.
    """
    from bayesbeam.trials.amplitude import amplitude_curves
    from bayesbeam.trials.amplitude_bins import amplitude_trend, tip_factor
    from bayesbeam.trials.modal_id import SignatureError

    t, y = trial.times, trial.values
    if not (np.isfinite(f1) and f1 > 0) or t[-1] - t[0] < 3 * 4.0 / f1:
        return {}
    try:
        c = amplitude_curves(t, y, f1=f1, n_modes=1, quantity=trial.quantity,
                             tip_factor=tip_factor(trial.beam))
    except SignatureError:
        return {}
    slope, se, n = amplitude_trend(c.amplitude_m, c.frequency[:, 0], c.frequency_se[:, 0],
                                   hop=c.hop_s, window=c.window_s)
    if not (np.isfinite(slope) and np.isfinite(se)) or n < 3:
        return {}
    return {"f1_slope": 1e3 * slope, "f1_slope_se": 1e3 * se}  # Hz/mm -> Hz/m


def _amplitude_starts(pb: Any, lin: Any, v: Mapping[str, float],
                      feats: Mapping[str, float],
                      which: Sequence[str] = ("drag", "friction")) -> list[dict[str, float]]:
    """Return starts whose drag or friction damps mode 1 about as much as the data show.

    The tip amplitude of mode 1 comes from its measured amplitude at the sensor
    (divided by ω1 per time derivative, scaled by the mode shape's tip/sensor ratio);
    :meth:`bayesbeam.physics.nonlinear.NonlinearForward.equivalent_damping` converts it to
    the damping ratio per unit drag and per unit friction. Starts: drag alone giving
    0.5 and 2 times the measured ζ1, friction alone 0.25 and 1 times it, each with the
    linear damping coefficients scaled by 1/(1 + factor) so that the total stays near
    the measured one (a linear fit has already absorbed the amplitude-dependent part);
    and, when the data's decay rate changes with amplitude beyond 2 standard errors
    (:func:`bayesbeam.trials.modal_id.decay_rate_vs_amplitude`: rate σ0 (1 + c) at the first
    sample), drag giving c σ0/ω1 with the linear damping giving σ0.

    Parameters
    ----------
    pb : Problem
        A problem whose model has ``drag`` or ``friction`` (otherwise no starts).
    lin : Forward
        Its linear part.
    v : mapping
        Sampled values (SI units) the starts are built from.
    feats : mapping
        The data's modal estimates (:meth:`_Engine.features`): ``f1`` (Hz), ``a1``
        (sensor units), ``sigma1`` (1/s), optionally ``excess``, ``excess_se``, ``rate0``.
    which : sequence of str
        The parameters to start (``drag``, ``friction``); those the model lacks are
        skipped.

    Returns
    -------
    list of dict
        Start points, name → value.
    """
    fwd = pb.forward
    if not hasattr(fwd, "equivalent_damping"):
        return []
    th = _fwd_row(pb, lin, v)
    om, _, phi = lin.modal_system(th[None])
    phi1 = np.asarray(phi)[..., 0].reshape(-1)
    ratio = abs(float(lin.fe.tip @ phi1) / float(lin.sensor @ phi1))
    order = {"displacement": 0, "velocity": 1, "acceleration": 2}[pb.trial.quantity]
    amp = feats["a1"] / om[0, 0] ** order * ratio
    X = np.array([[v[n] for n in pb.names]])
    P = pb.forward_params(X)[0]
    which = [n for n in which if n in fwd.param_names]
    if not which:
        return []
    for n in ("drag", "friction"):
        if n in fwd.param_names:
            P[list(fwd.param_names).index(n)] = 1.0
    zd, zf = fwd.equivalent_damping(P[None], amp)
    w1 = 2 * np.pi * feats["f1"]
    zeta1 = feats["sigma1"] / w1
    laws = [k for k in ("gamma", "c_d", "eta") if k in v]

    def start(name: str, zeta: float, per_unit: float, scale: float) -> dict[str, float]:
        w = dict(v)
        lo, hi = pb.priors[name].bounds
        w[name] = float(np.clip(zeta / per_unit, lo * 1.01, hi * 0.99))
        for k in laws:
            klo, khi = pb.priors[k].bounds
            w[k] = float(np.clip(v[k] * scale, klo * 1.01, khi * 0.99))
        return w

    out = []
    for name, per_unit, factors in (("drag", zd[0], (0.5, 2.0)), ("friction", zf[0], (0.25, 1.0))):
        if name in which and np.isfinite(per_unit) and per_unit > 0:
            out += [start(name, fac * zeta1, per_unit, 1 / (1 + fac)) for fac in factors]
    c, c_se, s0 = feats.get("excess", 0.0), feats.get("excess_se", np.inf), feats.get("rate0", 0.0)
    if "drag" in which and c > 2 * c_se and s0 > 0 and np.isfinite(zd[0]) and zd[0] > 0:
        out.append(start("drag", c * s0 / w1, zd[0], s0 / feats["sigma1"]))
    return out


def _root_on_ratio(pb: Any, lin: Any, v: Mapping[str, float], name: str, u_lo: float,
                   u_hi: float, target: float) -> float:
    """Value of structural parameter ``name`` at which ω2/ω1 equals ``target`` (bisection in u)."""
    prior = pb.priors[name]
    j = lin.param_names.index(name)
    row = _fwd_row(pb, lin, v)

    def miss(u: float) -> float:
        th = row.copy()
        th[j] = float(prior.from_u(u))
        om, _, _ = lin.modal_system(th[None])
        return float(om[0, 1] / om[0, 0] - target)

    return float(prior.from_u(sopt.brentq(miss, u_lo, u_hi, xtol=1e-10, maxiter=60)))


def _added_mass_starts(pb: Any, lin: Any, v: Mapping[str, float],
                       feats: Mapping[str, float], n_keep: int = 3) -> list[dict[str, float]]:
    """Return starts for a point mass anywhere on the span from the measured f2/f1 and f3/f1.

    At each of 15 positions from 0.3 L to the tip the mass that gives the measured f2/f1
    is solved for (where the prior's range brackets it; a mass near mode 2's node, about
    0.78 L, lowers f1 and hardly f2, one near 0.5 L lowers f2 more than f1, so f2/f1
    alone leaves a curve of (position, mass) pairs). Where f3 was measured, the pairs
    whose f3/f1 is closest to it are kept; otherwise ``n_keep + 1`` pairs spread along
    the curve (the likelihood, whose phase over the record depends on every frequency,
    is multimodal along it).
    """
    if "f2" not in feats:
        return []
    L = pb.trial.beam.length
    prior = pb.priors["added_mass"]
    jm, jx = lin.param_names.index("added_mass"), lin.param_names.index("added_mass_position")
    lo, hi = prior.bounds_u
    grid_u = np.linspace(lo, hi, 41)[1:-1]
    positions = L * np.linspace(0.3, 1.0, 15)
    row = _fwd_row(pb, lin, v)
    th = np.repeat(row[None], positions.size * grid_u.size, axis=0)
    th[:, jx] = np.repeat(positions, grid_u.size)
    th[:, jm] = np.tile(prior.from_u(grid_u), positions.size)
    om, _, _ = lin.modal_system(th)
    target = feats["f2"] / feats["f1"]
    miss = (om[:, 1] / om[:, 0] - target).reshape(positions.size, grid_u.size)
    found = []
    for k, x in enumerate(positions):
        sign = np.flatnonzero(miss[k, :-1] * miss[k, 1:] < 0)
        if sign.size == 0:
            continue
        i = int(sign[0])  # the smallest mass that matches: the least disturbing start
        w = {**v, "added_mass_position": float(x)}
        w["added_mass"] = _root_on_ratio(pb, lin, w, "added_mass", grid_u[i], grid_u[i + 1],
                                         target)
        found.append(w)
    if not found:
        return []
    if "f3" in feats and om.shape[1] > 2:
        th = np.array([_fwd_row(pb, lin, w) for w in found])
        o, _, _ = lin.modal_system(th)
        score = np.abs(o[:, 2] / o[:, 0] - feats["f3"] / feats["f1"])
        return [found[i] for i in np.argsort(score)[:n_keep]]
    idx = np.unique(np.linspace(0, len(found) - 1, n_keep + 1).round().astype(int))
    return [found[i] for i in idx]


def _set_damping(pb: Any, lin: Any, v: dict[str, float], feats: Mapping[str, float]) -> None:
    """Damping coefficients that reproduce the measured decay rates of modes 1 and 2.

    The decay rate of mode n is about half the diagonal modal damping, σ_n ≈ C_nn/2,
    and C is linear in the coefficients: non-negative least squares on σ1, σ2.
    """
    laws = [law for law in pb.model.laws]
    sig = [feats[k] for k in ("sigma1", "sigma2") if k in feats]
    if not sig:
        return
    cols = []
    for law in laws:
        w = dict(v)
        for other in ("gamma", "c_d", "eta"):
            if other in w:
                w[other] = 0.0
        key = {"viscous": "gamma", "kv": "c_d", "sh": "eta"}[law]
        w[key] = 1.0
        _, C, _ = lin.modal_system(_fwd_row(pb, lin, w)[None])
        cols.append(0.5 * np.diag(C[0])[: len(sig)])
    A = np.array(cols).T  # (modes, laws): decay rate per unit coefficient
    coef, _ = sopt.nnls(A / np.array(sig)[:, None], np.ones(len(sig)))
    for j, law in enumerate(laws):
        key = {"viscous": "gamma", "kv": "c_d", "sh": "eta"}[law]
        lo, hi = pb.priors[key].bounds
        # A law that nnls switches off starts where it alone gives 5 % of σ1.
        c = coef[j] if coef[j] > 0 else 0.05 * sig[0] / max(A[0, j], 1e-300)
        v[key] = float(np.clip(c, lo * 1.01, hi * 0.99))
