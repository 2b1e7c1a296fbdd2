"""Noise floor of a free-vibration record, estimated from the data alone.

A model fit reports a noise standard deviation σ; whether that σ is the sensor's noise
or the RMS of a misfit cannot be told from the fit itself. :func:`noise_floor` gives
the level to compare it with, using no physical model: it fits the record by the most
flexible description a free decay admits, a constant plus exponentially damped
sinusoids with free frequencies, decay rates, amplitudes and phases,

    ``y(t) = c + Σ_k e^{-σ_k t} (a_k cos 2π f_k t + b_k sin 2π f_k t) + ε(t)``,

and returns the residual standard deviation ``sqrt(RSS / (n - 2K - (2K + 1)))`` (K
components: 2K nonlinear and 2K + 1 linear parameters). A model fit whose σ is well
above it leaves systematic structure in its residuals (:mod:`bayesbeam.inference.adequacy`
compares the two).

Method
------
Components are added one at a time (matching pursuit), each followed by a refit of all:

1. **Find the next component** in the current residual (the record less its mean at
   first). On a uniform grid (non-uniform stamps are interpolated by a cubic spline,
   for *locating* peaks only), take the largest peak of the Hann-windowed periodogram
   of :func:`bayesbeam.trials.modal_id.periodogram` whose ordinate exceeds
   :data:`PEAK_FACTOR` (20) times the median ordinate below ``bandwidth``; if there is
   none, the largest such peak under a one-sided taper ``cos²(π t / 2T)``, which keeps
   the start of the record, where a fast-decaying component lives and the Hann window
   is ~0 (an acceleration record's higher modes may be gone within 50 ms). Peaks within
   ``2/T`` (the Hann main-lobe half-width, T the record length) of a component already
   fitted are passed over. Only the largest peak is taken per round because the others
   may be leakage of it (side lobes, or the noise ripple on its flanks), which the
   refit removes.
2. **Fit on the raw stamps** by variable projection (the amplitudes and c solved by
   linear least squares inside the optimisation of ``(f_k, σ_k)``; Golub & Pereyra
   1973, SIAM J. Numer. Anal. 10, 413-432) with the fitter of
   :func:`bayesbeam.trials.modal_id.damped_sinusoids`, warm-started at the previous
   fit; the new component starts at the peak frequency with
   ``σ = π × (half-power width − the window's own width)``.
3. **Stop** when no peak is left, ``max_modes`` components are in, or two fitted
   components are closer than ``1/T`` (not resolved by the record: the content there is
   not a sum of free decays, and further components only pile up).

The threshold: for white noise of variance s² the Hann ordinates are exponential with
mean ``6 s²/n``, median ``ln 2`` times that, so a noise ordinate passes with probability
``e^{-20 ln 2} = 1e-6``: by noise alone, about one record in a thousand (n = 2048) gets
a spurious component (imperfect gridding of jittered stamps adds a few more), which
costs 4 degrees of freedom and fits a little noise (bias ~0.1 %). A steady sinusoid is
missed only if its amplitude is below ``sqrt(20 ln 2 · 6) s/√n = 9.1 s/√n`` (0.2 s at
n = 2048); it then inflates the estimate by at most ``21/n`` relative (1 % at
n = 2048).

Assumptions and their effect
----------------------------
* Free decay: every component has a constant frequency and decay rate (a linear
  system). Amplitude-dependent damping (air drag, friction) or frequency (a stiffening
  or softening spring), a forced or transient input after the start, or a drifting
  baseline are only approximated (by extra components while the residual still shows
  a resolved peak), so the estimate is then an **upper bound** on the noise. So is
  content above ``bandwidth``, which is left in the residual, and a component too weak
  for the threshold (see above).
* The noise is roughly white over the band (the threshold is relative to the
  periodogram's median); coloured noise is estimated correctly in total as long as it
  does not form peaks 20 times its median level.
* Non-uniform stamps are used as they are in the fit; only peak finding interpolates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from bayesbeam._util import one_blas_thread
from bayesbeam.trials.modal_id import _fit_modes, periodogram, uniform_grid

__all__ = ["PEAK_FACTOR", "NoiseFloor", "NoiseFloorError", "noise_floor"]

#: A periodogram ordinate counts as a peak above this multiple of the median ordinate.
PEAK_FACTOR = 20.0

#: Fewest samples accepted.
MIN_SAMPLES = 64

# Zero-padding factor of the spectra (as periodogram's default).
_PAD = 4


class NoiseFloorError(ValueError):
    """Input to :func:`noise_floor` is invalid; the message says how to fix it."""


@dataclass(frozen=True)
class NoiseFloor:
    """Noise level of a record from a model-free fit of damped sinusoids.

    Attributes
    ----------
    sd : float
        Estimated noise standard deviation, units of the signal:
        ``sqrt(RSS / dof)``. An upper bound when the record is not a sum of
        constant-rate damped sinusoids (see :mod:`bayesbeam.trials.noise`).
    n_components : int
        Damped sinusoids fitted, K.
    frequencies : tuple of float
        Their fitted frequencies in Hz, increasing.
    dof : int
        Residual degrees of freedom, ``n - 4K - 1``.
    method : str
        ``"damped_sinusoids+constant"``, or ``"constant"`` when no component was found
        (then ``sd`` is the sample standard deviation).
    """

    sd: float
    n_components: int
    frequencies: tuple[float, ...]
    dof: int
    method: str


def _on_grid(times: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the series on the uniform grid ``times[0] + k dt`` (dt the mean step).

    Uniform stamps are kept as they are. Otherwise a cubic spline interpolates: its error
    on a sinusoid is ``(ω h)⁴ / 384`` of the amplitude (6 % at 2.8 samples per period)
    against ``(ω h)² / 8`` (60 %) for :func:`bayesbeam.trials.modal_id.uniform_grid`'s
    linear interpolation, whose error spreads a strong high-frequency component into a
    broadband floor that hides weaker peaks.
    """
    grid, y_lin, dt = uniform_grid(times, values)
    if grid.size != times.size or np.max(np.abs(grid - times)) <= 1e-6 * dt:
        return grid, y_lin  # uniform, or a uniform grid with holes (filled by the mean)
    return grid, CubicSpline(times, values)(grid)


def _start_taper_spectrum(grid: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Power spectrum under the one-sided taper ``cos²(π t / 2T)`` (1 at the start)."""
    n = y.size
    dt = float(grid[1] - grid[0])
    w = np.cos(0.5 * np.pi * np.arange(n) / (n - 1)) ** 2
    # Remove the weighted mean so that the zero-frequency ordinate is zero.
    yc = y - float(w @ y) / float(w.sum())
    nfft = int(2 ** math.ceil(math.log2(_PAD * n)))
    amp = np.abs(np.fft.rfft(yc * w, nfft)) * 2.0 / w.sum()
    return np.fft.rfftfreq(nfft, dt), amp**2


def _peaks(f: np.ndarray, power: np.ndarray, bandwidth: float, window_width: float
           ) -> list[tuple[float, float, float]]:
    """Local maxima above ``PEAK_FACTOR`` × median, largest first.

    Returns ``(frequency Hz, start decay rate 1/s, ordinate / threshold)`` per peak; the
    decay rate is ``π`` times the half-power width less the window's own width
    ``window_width`` (Hz), floored at 0.1 % of critical.
    """
    band = np.flatnonzero((f > 0) & (f <= bandwidth))
    if band.size < 3:
        return []
    p = power[band]
    thr = PEAK_FACTOR * float(np.median(p))
    if not thr > 0:
        return []
    inner = np.arange(1, p.size - 1)
    is_max = (p[inner] > thr) & (p[inner] >= p[inner - 1]) & (p[inner] > p[inner + 1])
    out = []
    df = float(f[1] - f[0])
    for i in inner[is_max]:
        half = 0.5 * p[i]
        below_left = np.flatnonzero(p[:i] < half)
        below_right = np.flatnonzero(p[i + 1 :] < half)
        lo = below_left[-1] + 1 if below_left.size else 0
        hi = i + below_right[0] if below_right.size else p.size - 1
        width = (hi - lo + 1) * df
        fk = float(f[band[i]])
        sigma = max(math.pi * (width - window_width), 1e-3 * 2 * math.pi * fk)
        out.append((fk, sigma, float(p[i] / thr)))
    out.sort(key=lambda c: -c[2])
    return out


def _next_component(times: np.ndarray, r: np.ndarray, bandwidth: float, have: np.ndarray
                    ) -> tuple[float, float] | None:
    """Return the next component for the residual ``r``: ``(frequency Hz, decay rate 1/s)``.

    The largest peak of the Hann spectrum, or when it has none, of the start-weighted
    spectrum; peaks within the Hann main-lobe half-width ``2/T`` of a component already
    fitted (frequencies ``have``, Hz) are passed over: two components closer than that
    are not resolved by the record. None when no peak is left.
    """
    t_span = float(times[-1] - times[0])
    grid, rg = _on_grid(times, r)
    f, amp = periodogram(grid, rg, pad=_PAD)
    # Half-power widths of the main lobes, Hann and one-sided taper: 1.47 and 1.28 bins.
    spectra = [(f, amp**2, 1.47 / t_span), (*_start_taper_spectrum(grid, rg), 1.28 / t_span)]
    for f, power, width in spectra:
        for fk, sk, _ in _peaks(f, power, bandwidth, width):
            if np.all(np.abs(have - fk) > 2.0 / t_span):
                return fk, sk
    return None


def noise_floor(times: np.ndarray, values: np.ndarray, *, bandwidth: float | None = None,
                max_modes: int = 12) -> NoiseFloor:
    """Noise standard deviation of a free-vibration record, with no physical model.

    The record is fitted by a constant plus up to ``max_modes`` exponentially damped
    sinusoids found as spectral peaks (see :mod:`bayesbeam.trials.noise` for the
    method and its assumptions), and the residual standard deviation is returned.

    Parameters
    ----------
    times : ndarray, shape (n,)
        Sample times in s, strictly increasing (non-uniform stamps are used as they are
        in the fit).
    values : ndarray, shape (n,)
        Signal, any units (the result is in the same units); ``n >= 64``, finite.
    bandwidth : float, optional
        Components are sought only below this frequency, Hz (e.g. the sensor's band);
        content above it counts as noise. None: the Nyquist frequency of the median
        step.
    max_modes : int
        Most damped sinusoids fitted (>= 0); at most ``(n - 1) // 8`` are used, so that
        half the samples remain as residual degrees of freedom.

    Returns
    -------
    NoiseFloor
        ``sd`` in the units of ``values``, the components' frequencies in Hz and the
        residual degrees of freedom.

    Raises
    ------
    NoiseFloorError
        For arrays that are not 1-D or differ in shape, fewer than 64 samples,
        non-finite values, times not strictly increasing, a bandwidth that is not a
        positive number, or a negative ``max_modes``.
    """
    t = np.asarray(times, dtype=float)
    y = np.asarray(values, dtype=float)
    if t.ndim != 1 or t.shape != y.shape:
        raise NoiseFloorError(
            f"times and values must be 1-D arrays of the same length, got shapes {t.shape} "
            f"and {y.shape}"
        )
    n = t.size
    if n < MIN_SAMPLES:
        raise NoiseFloorError(
            f"record has {n} samples; a noise floor needs at least {MIN_SAMPLES} (use a "
            "longer record)"
        )
    bad = int(np.count_nonzero(~np.isfinite(t)) + np.count_nonzero(~np.isfinite(y)))
    if bad:
        raise NoiseFloorError(
            f"times and values hold {bad} non-finite value(s) (NaN or inf); drop those "
            "samples first"
        )
    steps = np.diff(t)
    if np.any(steps <= 0):
        raise NoiseFloorError(
            "times must be strictly increasing; sort the record and drop duplicate stamps"
        )
    if bandwidth is None:
        band = 0.5 / float(np.median(steps))
    else:
        try:
            band = float(bandwidth)
        except (TypeError, ValueError):
            band = math.nan
        if not (math.isfinite(band) and band > 0):
            raise NoiseFloorError(
                f"bandwidth must be a positive frequency in Hz (or None for the Nyquist "
                f"frequency), got {bandwidth!r}"
            )
    if not (isinstance(max_modes, (int, np.integer)) and max_modes >= 0):
        raise NoiseFloorError(f"max_modes must be an integer >= 0, got {max_modes!r}")
    cap = min(int(max_modes), (n - 1) // 8)

    t0 = t - t[0]
    span = float(t0[-1])
    r = y - y.mean()
    p = np.empty(0)
    # The fit solves thousands of tall, thin least-squares problems (n × (2K + 1));
    # OpenBLAS threads only slow those down (measured 100x on a loaded 2-core machine).
    with one_blas_thread():
        for k in range(cap):  # one component per round
            new = _next_component(t, r, band, p[:k])
            if new is None:
                break
            f0 = np.append(p[:k], new[0])
            s0 = np.append(p[k:], new[1])
            fit = _fit_modes(t0, y, f0, s0, offset=True, excess=False)
            p, r = fit["p"], fit["resid"]
            fk = np.sort(p[: p.size // 2])
            if fk.size > 1 and np.min(np.diff(fk)) < 1.0 / span:
                # Two components closer than the record resolves: the content there is
                # not a sum of free decays (e.g. a drifting frequency), more components
                # only pile up, and the fit turns degenerate and slow. Stop: sd is then
                # an upper bound.
                break
    k = p.size // 2
    dof = n - 4 * k - 1
    sd = math.sqrt(float(r @ r) / dof)
    return NoiseFloor(
        sd=sd,
        n_components=k,
        frequencies=tuple(sorted(float(v) for v in p[:k])),
        dof=dof,
        method="damped_sinusoids+constant" if k else "constant",
    )
