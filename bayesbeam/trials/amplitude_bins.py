"""Helpers of :mod:`bayesbeam.trials.amplitude`: amplitude bins, sensor-to-tip factor."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayesbeam._util import finite_or_none

__all__ = ["AmplitudeBin", "bin_by_amplitude", "overlap_factor", "tip_factor"]


@dataclass(frozen=True)
class AmplitudeBin:
    """Window results averaged over one mode-1 amplitude bin.

    Attributes
    ----------
    lo, hi : float
        Bin edges, mode-1 amplitude in record units.
    n : int
        Windows in the bin.
    amplitude, amplitude_m : float
        Geometric-mean mode-1 amplitude (record units; displacement in m).
    f1, f1_se, zeta1, zeta1_se : float
        Mean mode-1 frequency (Hz) and damping ratio, with standard errors.
    f2, f2_se, ratio, ratio_se, zeta2, zeta2_se : float
        Same for mode 2 and f2/f1 (NaN when no window of the bin resolves mode 2).

    Notes
    -----
    The standard error of a bin mean is ``sqrt(mean(se²) / n · g)`` where ``se`` are the
    windows' standard errors and ``g = 1 + 2 Σ_j (1 - j/n) ρ_j`` accounts for windows
    sharing samples: ``ρ_j = max(0, 1 - j·hop/window)`` is the overlap of windows j
    apart (``g ≈ 2`` for the default hop of half a window).
    """

    lo: float
    hi: float
    n: int
    amplitude: float
    amplitude_m: float
    f1: float
    f1_se: float
    zeta1: float
    zeta1_se: float
    f2: float
    f2_se: float
    ratio: float
    ratio_se: float
    zeta2: float
    zeta2_se: float

    def to_json_dict(self) -> dict[str, Any]:
        """Return the bin as a strict-JSON dictionary (NaN as None).

        Returns
        -------
        dict
        """
        return {k: (v if isinstance(v, int) else finite_or_none(v))
                for k, v in self.__dict__.items()}


def overlap_factor(n: int, hop: float, window: float) -> float:
    """Variance factor of a mean of n consecutive window estimates that share samples.

    Parameters
    ----------
    n : int
        Number of consecutive windows averaged.
    hop, window : float
        Hop between window starts and window length, s.

    Returns
    -------
    float
        ``g = 1 + 2 Σ_{j<n} (1 - j/n) ρ_j`` with ``ρ_j = max(0, 1 - j·hop/window)`` (the
        fraction of samples two windows j apart share, taken as their correlation).
    """
    j = np.arange(1, n)
    rho = np.clip(1.0 - j * hop / window, 0.0, 1.0)
    return float(1.0 + 2.0 * np.sum((1.0 - j / n) * rho)) if n > 1 else 1.0


def _bin_mean(v: np.ndarray, se: np.ndarray, g: float) -> tuple[float, float]:
    ok = np.isfinite(v) & np.isfinite(se)
    if not np.any(ok):
        return math.nan, math.nan
    return float(np.mean(v[ok])), float(math.sqrt(np.mean(se[ok] ** 2) / ok.sum() * g))


def bin_by_amplitude(amp: np.ndarray, amp_m: np.ndarray, f: np.ndarray, f_se: np.ndarray,
                     z: np.ndarray, z_se: np.ndarray, ratio: tuple[np.ndarray, np.ndarray],
                     n_bins: int, hop: float, window: float) -> tuple[AmplitudeBin, ...]:
    """Average window estimates over log-spaced bins of mode-1 amplitude.

    Parameters
    ----------
    amp, amp_m : ndarray, shape (W,)
        Mode-1 amplitude per window (record units; displacement in m), NaN where
        unresolved.
    f, f_se, z, z_se : ndarray, shape (W, K)
        Frequencies (Hz), damping ratios and their standard errors.
    ratio : tuple of ndarray, shape (W,)
        f2/f1 and its standard error.
    n_bins : int
        Number of bins between the smallest and largest amplitude.
    hop, window : float
        Hop and window length in s (for :func:`overlap_factor`).

    Returns
    -------
    tuple of AmplitudeBin
        Non-empty bins, smallest amplitude first.
    """
    ok = np.isfinite(amp) & (amp > 0)
    if not np.any(ok):
        return ()
    edges = np.geomspace(amp[ok].min(), amp[ok].max() * (1 + 1e-12), n_bins + 1)
    out = []
    K = f.shape[1]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = ok & (amp >= lo) & (amp < hi)
        n = int(sel.sum())
        if n == 0:
            continue
        g = overlap_factor(n, hop, window)
        vals = [*_bin_mean(f[sel, 0], f_se[sel, 0], g), *_bin_mean(z[sel, 0], z_se[sel, 0], g)]
        if K > 1:
            vals += [*_bin_mean(f[sel, 1], f_se[sel, 1], g),
                     *_bin_mean(ratio[0][sel], ratio[1][sel], g),
                     *_bin_mean(z[sel, 1], z_se[sel, 1], g)]
        else:
            vals += [math.nan] * 6
        out.append(AmplitudeBin(float(lo), float(hi), n,
                                float(np.exp(np.mean(np.log(amp[sel])))),
                                float(np.exp(np.mean(np.log(amp_m[sel])))), *vals))
    return tuple(out)


def tip_factor(beam: Any, n_elements: int = 24) -> float:
    """Ratio of mode-1 displacement at the tip to that at the sensor (FE mode shape).

    Parameters
    ----------
    beam : bayesbeam.physics.beam.Beam
        The beam (mass and stiffness distributions, tip mass, sensor position).
    n_elements : int
        Hermite elements of the mode-shape computation.

    Returns
    -------
    float
        ``φ1(L) / φ1(x_s)`` (1 when the sensor is at the tip). The root spring and the
        stiffness gradient are ignored (the clamp taken as rigid).
    """
    import scipy.linalg as sla

    from bayesbeam.physics.fem import assemble

    fe = assemble(beam, n_elements, root_dof=False)
    _, vec = sla.eigh(fe.K, fe.M, subset_by_index=[0, 0])
    v = vec[:, 0]
    return float(fe.tip @ v / (fe.shape(beam.sensor_x)[0] @ v))


def amplitude_trend(amplitude_m: np.ndarray, values: np.ndarray, se: np.ndarray, *,
                    hop: float, window: float) -> tuple[float, float, int]:
    """Slope of a window estimate against the mode-1 amplitude, per mm, with its se.

    Weighted least squares of ``values`` on ``1e3 * amplitude_m`` (weights ``1/se²``);
    the slope's standard error is inflated by the window-overlap variance factor
    (:func:`overlap_factor` over the windows used), as neighbouring windows share
    samples. A linear trend summarises what the amplitude curves show: f1 falling with
    amplitude is softening, ζ1 rising with it drag, ζ1 falling with it friction.

    Parameters
    ----------
    amplitude_m : ndarray, shape (W,)
        Mode-1 tip amplitude of each window, m.
    values, se : ndarray, shape (W,)
        The estimate (e.g. f1 in Hz or ζ1) and its standard error; NaN where unresolved.
    hop, window : float
        Hop and window length, s.

    Returns
    -------
    slope : float
        Per mm of amplitude (NaN with fewer than 3 usable windows or no amplitude spread).
    slope_se : float
    n : int
        Windows used.
    """
    a = 1e3 * np.asarray(amplitude_m, dtype=float)
    v, s = np.asarray(values, dtype=float), np.asarray(se, dtype=float)
    ok = np.isfinite(a) & np.isfinite(v) & np.isfinite(s) & (s > 0)
    n = int(ok.sum())
    if n < 3 or np.ptp(a[ok]) <= 0:
        return math.nan, math.nan, n
    w = 1.0 / s[ok] ** 2
    X = np.column_stack([np.ones(n), a[ok]])
    cov = np.linalg.inv(X.T @ (w[:, None] * X))
    beta = cov @ (X.T @ (w * v[ok]))
    g = overlap_factor(n, hop, window)
    return float(beta[1]), float(math.sqrt(cov[1, 1] * g)), n
