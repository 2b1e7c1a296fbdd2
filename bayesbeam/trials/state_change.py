"""A change of state within a record: mode 1's frequency and damping jumping at one moment.

A free decay whose clamp slips, whose joint goes from slipping to sticking or whose
attachment loosens mid-record changes its frequency and damping at one moment; the
catalogue's damping laws all change them smoothly with amplitude, and a fit of the
whole record then averages the two states. This module finds such a jump in the
window-by-window estimates of :func:`bayesbeam.trials.amplitude.amplitude_curves` and
reports its time and what jumps, whether or not any model explains it.

Method (a two-sided local jump test, as in jump detection for nonparametric regression):

* windows that do not overlap (every ``round(window / hop)``-th one) give independent
  estimates ``f_i ± s_f,i`` and ``ζ_i ± s_ζ,i`` at centre times ``t_i``; windows in
  which mode 1 decays by more than a factor e (``2π ζ f T > 1``, e.g. the last cycles
  before dry friction stops the motion) hold no modal estimate and are left out;
* at each window centre ``t_c`` and for each gap ``g`` (0, 1, 2 windows left out on
  each side: a sudden jump, or a change spread over up to ~5 windows), the ``side``
  windows before the gap and the ``side`` after it are fitted (weighted least squares,
  f and ζ each) with a smooth function of the mode-1 amplitude ``A`` plus a jump ``Δ``
  at ``t_c``: ``c0 + c1 A + c2 A²`` for f, ``c0 + c1 A + c2/A`` for ζ. The catalogue's
  amplitude laws at first order — quadratic drag (ζ ∝ A), dry friction (ζ ∝ 1/A), a
  cubic stiffness (Δf ∝ A²) — are carried exactly and leave ``Δ ≈ 0``; a change of state
  does not;
* the jump's standard error comes from the window errors, scaled up (never down) by the
  record's typical misfit: the median reduced χ² of all the local fits of that curve
  (scatter beyond the stated errors widens it; a fit's own χ², from ~6 degrees of
  freedom, was too noisy a scale and made wiggles of measured curves significant); the
  statistic ``z_f² + z_ζ²`` is χ²(2) when nothing jumps, its p-value
  Bonferroni-corrected for the ``(t_c, g)`` tried;
* a change is reported when the corrected p-value is below ``alpha`` (1e-3), a jump
  reaches ``min_sigma`` (4) standard errors **and** ``min_scatter`` (2) times the
  window-to-window scatter of that curve about its lines (a change of state is a jump
  one would see in the curve, not only a formally significant one in a long, clean
  record).

The time is the centre of the best ``(t_c, g)`` ± ``(g + ½)`` windows. The jump ``Δ`` is
what the local model cannot carry smoothly; where a change is spread over more than the
gap, its sign and size depend on that model, so the record also states the levels
before and after (weighted means of the ``side`` windows on each side), which include
any smooth trend across the change. Alternatives tried and rejected: gaps of 4 or 6
windows (the smooth part then spans so much amplitude that smooth measured records and
the drag-with-cubic-stiffness record were flagged, or the jump changed sign), a straight
line in ``A`` (smooth measured records flagged), and time instead of amplitude as the
abscissa (the smooth nonlinear record flagged). Checked against
direct integrations of an oscillator whose stiffness and damping jump at a known time
(suddenly and spread over seconds), and against records with strong smooth amplitude
dependence (quadratic drag with cubic stiffness, dry friction) and constant parameters
that must not be flagged (``tests/trials/test_state_change.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.stats as sstats

from bayesbeam._util import finite_or_none

__all__ = ["StateChange", "state_change"]

#: Default test settings (see the module docstring).
DEFAULTS: dict[str, Any] = {"alpha": 1e-3, "min_sigma": 4.0, "min_scatter": 2.0, "side": 5,
                            "gaps": (0, 1, 2)}


@dataclass(frozen=True)
class StateChange:
    """Result of :func:`state_change` (SI: s, Hz; the damping ratio is a pure number).

    Attributes
    ----------
    tested : bool
        False when the record has too few resolved windows to test (``reason`` says why).
    found : bool
        A change of state was detected (see the module docstring for the rule).
    time_s, time_halfwidth_s : float or None
        Time of the (largest) jump and the half-width of its interval, s.
    frequency_step_hz, frequency_step_se : float or None
        ``Δf1`` (after minus before) and its standard error, Hz.
    zeta_step, zeta_step_se : float or None
        ``Δζ1`` and its standard error.
    p_value : float or None
        Bonferroni-corrected p-value of the largest jump (1: no evidence).
    n_windows : int
        Independent windows used.
    reason : str
        One sentence: what was found, or why nothing was tested.
    levels : dict
        ``frequency_before_hz``, ``frequency_after_hz``, ``zeta_before``, ``zeta_after``:
        weighted means of the ``side`` windows either side of the (largest) jump, smooth
        trend included; ``before_s``, ``after_s``: the centre times of the first and last
        of those windows (empty when not tested).
    """

    tested: bool
    found: bool
    time_s: float | None
    time_halfwidth_s: float | None
    frequency_step_hz: float | None
    frequency_step_se: float | None
    zeta_step: float | None
    zeta_step_se: float | None
    p_value: float | None
    n_windows: int
    reason: str
    levels: dict[str, Any] = field(default_factory=dict)

    def to_json_dict(self) -> dict[str, Any]:
        """Return the result as strict JSON (units in the key names: s, hz)."""
        out: dict[str, Any] = {"tested": self.tested, "found": self.found,
                               "n_windows": self.n_windows, "reason": self.reason}
        for k in ("time_s", "time_halfwidth_s", "frequency_step_hz", "frequency_step_se",
                  "zeta_step", "zeta_step_se", "p_value"):
            out[k] = finite_or_none(getattr(self, k))
        out["levels"] = {k: ([finite_or_none(x) for x in v] if isinstance(v, list)
                             else finite_or_none(v)) for k, v in self.levels.items()}
        return out


def _untested(n: int, reason: str) -> StateChange:
    return StateChange(False, False, None, None, None, None, None, None, None, n, reason)


def state_change(curves: Any, *, alpha: float = DEFAULTS["alpha"],
                 min_sigma: float = DEFAULTS["min_sigma"],
                 min_scatter: float = DEFAULTS["min_scatter"],
                 side: int = DEFAULTS["side"]) -> StateChange:
    """Test mode 1's frequency and damping curves for a jump at one moment.

    Parameters
    ----------
    curves : AmplitudeCurves
        From :func:`bayesbeam.trials.amplitude.amplitude_curves` (mode 1 is used).
    alpha : float, default 1e-3
        Level of the Bonferroni-corrected test.
    min_sigma : float, default 4
        A reported jump must reach this many standard errors in f or ζ ...
    min_scatter : float, default 2
        ... and this many times that curve's window-to-window scatter.
    side : int, default 5
        Independent windows in each one-sided line (at least 3).

    Returns
    -------
    StateChange

    Raises
    ------
    ValueError
        For settings out of range (the message names the setting).
    """
    if not (0.0 < alpha < 1.0):
        raise ValueError(f"alpha must lie in (0, 1), got {alpha!r}")
    if not (isinstance(side, int) and side >= 3):
        raise ValueError(f"side must be an int >= 3, got {side!r}")
    if not (min_sigma > 0 and min_scatter >= 0):
        raise ValueError(f"min_sigma must be > 0 and min_scatter >= 0, got {min_sigma!r}, "
                         f"{min_scatter!r}")
    window = float(curves.window_s)
    stride = max(1, round(window / float(curves.hop_s)))
    t = np.asarray(curves.centre, dtype=float)[::stride]
    f = np.asarray(curves.frequency, dtype=float)[::stride, 0]
    sf = np.asarray(curves.frequency_se, dtype=float)[::stride, 0]
    z = np.asarray(curves.zeta, dtype=float)[::stride, 0]
    sz = np.asarray(curves.zeta_se, dtype=float)[::stride, 0]
    amp = np.asarray(curves.amplitude, dtype=float)[::stride, 0]
    with np.errstate(invalid="ignore"):
        ok = (np.isfinite(t) & np.isfinite(f) & np.isfinite(z) & np.isfinite(sf)
              & np.isfinite(sz) & (sf > 0) & (sz > 0) & np.isfinite(amp) & (amp > 0)
              & (2 * np.pi * z * f * window < 1.0))
    t, f, sf, z, sz, amp = (a[ok] for a in (t, f, sf, z, sz, amp))
    n = t.size
    fits = []  # (i, g, left, right, jumps, raw se, local reduced χ², scatter) per try
    for i in range(n):
        for g in DEFAULTS["gaps"]:
            left = np.arange(i - g - side, i - g)
            right = np.arange(i + g + 1, i + g + 1 + side)
            if left[0] < 0 or right[-1] >= n:
                continue
            both = np.concatenate([left, right])
            out = [_local_step(amp[both], y[both], s[both], amp[i], inverse=inverse)
                   for y, s, inverse in ((f, sf, False), (z, sz, True))]
            fits.append((i, g, left, right, *(np.array(col) for col in zip(*out, strict=True))))
    if not fits:
        return _untested(n, f"{n} independent windows with mode 1 resolved; the test needs "
                            f"at least {2 * side + 1}")
    # One error scale per curve for the whole record: the median reduced χ² of all the
    # local fits (never below 1). A single fit's own χ² (2 side - 4 degrees of freedom)
    # is too noisy a scale: it made small wiggles of measured curves look significant.
    # The median is robust to the few fits that straddle a real change.
    scale = np.maximum(1.0, np.median(np.array([fit[6] for fit in fits]), axis=0))
    tried = len(fits)
    chi2s = [float(np.sum((fit[4] / (fit[5] * np.sqrt(scale))) ** 2)) for fit in fits]
    k = int(np.argmax(chi2s))
    i, g, left, right, d, raw_se, _, scatter = fits[k]
    se = raw_se * np.sqrt(scale)
    levels = [[_mean(y[idx], s[idx]) for idx in (left, right)] for y, s in ((f, sf), (z, sz))]
    best = {"i": i, "g": g, "chi2": chi2s[k], "levels": levels}
    p_adj = min(1.0, float(sstats.chi2.sf(best["chi2"], 2)) * tried)
    sigmas = np.abs(d) / se
    with np.errstate(divide="ignore", invalid="ignore"):
        seen_each = np.where(scatter > 0, np.abs(d) / scatter, np.inf)
    strong = sigmas >= min_sigma
    seen = float(np.max(seen_each[strong] if np.any(strong) else seen_each))
    found = bool(p_adj < alpha and np.any(strong) and seen >= min_scatter)
    tc = float(t[best["i"]])
    half = (best["g"] + 0.5) * window
    (f_before, f_after), (z_before, z_after) = best["levels"]
    what = (f"f1 {d[0]:+.3g} ± {se[0]:.2g} Hz, ζ1 {d[1]:+.3g} ± {se[1]:.2g}; {seen:.1f} x "
            "the window-to-window scatter")
    if found:
        reason = (f"change of state at t = {tc:.3g} ± {half:.2g} s (f1 {f_before:.5g} → "
                  f"{f_after:.5g} Hz, ζ1 {z_before:.3g} → {z_after:.3g} across it): jump "
                  f"beyond the smooth amplitude trend {what} (corrected p = {p_adj:.1g}; no "
                  "smooth change with amplitude explains it)")
    else:
        reason = (f"no change of state: the largest jump ({what}, at t = {tc:.3g} s) has "
                  f"corrected p = {p_adj:.2g} and {float(sigmas.max()):.1f} standard errors "
                  f"(a change needs p < {alpha:g}, {min_sigma:g} standard errors and "
                  f"{min_scatter:g} x the scatter)")
    return StateChange(True, found, tc, half, float(d[0]), float(se[0]), float(d[1]),
                       float(se[1]), p_adj, n, reason,
                       levels={"frequency_before_hz": f_before, "frequency_after_hz": f_after,
                               "zeta_before": z_before, "zeta_after": z_after,
                               "before_s": [float(t[left[0]]), float(t[left[-1]])],
                               "after_s": [float(t[right[0]]), float(t[right[-1]])]})


def _local_step(a: np.ndarray, y: np.ndarray, s: np.ndarray, a0: float, *,
                inverse: bool = False) -> tuple[float, float, float, float]:
    """Fit ``y ≈ smooth(A) + Δ·[A < A0]`` (weights ``1/s``): Δ, its se, χ²/dof and RMS.

    ``A`` is the mode-1 amplitude, which falls with time: ``A < A0`` is "after". The
    smooth part is ``c0 + c1 A + c2 A²`` for the frequency (a cubic stiffness gives
    Δf ∝ A²) and ``c0 + c1 A + c2/A`` for the damping ratio (quadratic drag gives ζ ∝ A,
    dry friction ζ ∝ 1/A; ``inverse=True``): the first-order amplitude laws of the
    catalogue are carried exactly and leave ``Δ ≈ 0``. The step's standard error is the
    weights' (the caller scales it by the record's typical reduced χ²); the RMS of the
    residuals is in the units of ``y``.
    """
    span = max(float(np.ptp(a)), 1e-300)
    tau = (a - a0) / span
    third = a.min() / a if inverse else tau**2
    X = np.column_stack([np.ones_like(tau), tau, third, (tau < 0).astype(float)])
    w = 1.0 / s
    Xw = X * w[:, None]
    coef, *_ = np.linalg.lstsq(Xw, y * w, rcond=None)
    r = y * w - Xw @ coef
    chi2_red = float(r @ r) / max(a.size - X.shape[1], 1)
    cov = np.linalg.pinv(Xw.T @ Xw)
    resid = y - X @ coef
    return (float(coef[3]), float(math.sqrt(cov[3, 3])), chi2_red,
            float(np.sqrt(np.mean(resid**2))))


def _mean(y: np.ndarray, s: np.ndarray) -> float:
    """Inverse-variance weighted mean."""
    w = 1.0 / s**2
    return float(np.sum(w * y) / np.sum(w))
