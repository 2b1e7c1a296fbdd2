"""Residual of a windowed modal fit: blend, spectrogram and spectral lines.

Used by :func:`bayesbeam.trials.amplitude.amplitude_curves`: after the window-by-window
fits of damped sinusoids, what is left (data minus the blended fit) shows what the
modal description misses: harmonics of mode 1 (a nonlinear restoring force or sensor),
mains pick-up, unfitted modes.

* :func:`blend_windows`: the windows' fitted signals cross-faded with triangular weights;
* :func:`residual_spectrogram`: short-time amplitude spectrum of the residual, computed
  on a uniform linear interpolation of the residual to its mean step (the stamps may
  be non-uniform; the interpolation's low-pass is negligible well below the Nyquist
  frequency, which is all a look at the residual needs);
* :func:`residual_lines`: peaks of the residual's periodogram standing out by more
  than a factor above the local median level, labelled as harmonics 2f1..5f1 (within 1 %),
  mains (50/60 Hz and multiples within 0.5 Hz) or "unexplained".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.signal as ssig

from bayesbeam._util import finite_or_none
from bayesbeam.trials.modal_id import periodogram

__all__ = [
    "ResidualLine",
    "blend_windows",
    "label_line",
    "residual_lines",
    "residual_spectrogram",
]

#: Mains frequencies in Hz; lines within MAINS_TOL Hz of a multiple are labelled mains.
MAINS = (50.0, 60.0)
MAINS_TOL = 0.5
#: Relative tolerance of a harmonic n f1 (n = 2..HARMONICS).
HARMONIC_TOL = 0.01
HARMONICS = 5


@dataclass(frozen=True)
class ResidualLine:
    """One spectral line of the residual.

    Attributes
    ----------
    frequency : float
        Hz.
    amplitude : float
        Periodogram peak (a steady sinusoid of amplitude A peaks at about A), record units.
    ratio : float
        Peak over the local median level of the periodogram.
    label : str
        ``"2f1"`` .. ``"5f1"``; ``"mains 50 Hz"``, ``"mains 3x60 Hz"``, ...; or
        ``"unexplained"`` (see :func:`label_line`).
    """

    frequency: float
    amplitude: float
    ratio: float
    label: str

    def to_json_dict(self) -> dict[str, Any]:
        """Return the line as a strict-JSON dictionary.

        Returns
        -------
        dict
        """
        return {"frequency_hz": finite_or_none(self.frequency),
                "amplitude": finite_or_none(self.amplitude),
                "ratio_to_median": finite_or_none(self.ratio), "label": self.label}


def blend_windows(times: np.ndarray, bounds: Sequence[tuple[int, int, float]],
                  models: Sequence[np.ndarray], window: float) -> np.ndarray:
    """Cross-fade the windows' fitted signals into one signal.

    Parameters
    ----------
    times : ndarray, shape (T,)
        Sample times in s.
    bounds : sequence of (int, int, float)
        Per window: first sample, one past the last sample, centre time in s.
    models : sequence of ndarray
        Per window: the fitted signal on its samples, shape (i1 - i0,).
    window : float
        Window length in s.

    Returns
    -------
    ndarray, shape (T,)
        ``Σ w_i m_i / Σ w_i`` with triangular weights ``w_i = max(1 - 2|t - t_c|/window,
        1e-3)`` (so samples covered by one window only take its fit); NaN where no window
        covers a sample.
    """
    t = np.asarray(times, dtype=float)
    num = np.zeros(t.size)
    den = np.zeros(t.size)
    for (i0, i1, tc), m in zip(bounds, models, strict=True):
        w = np.maximum(1.0 - 2.0 * np.abs(t[i0:i1] - tc) / window, 1e-3)
        num[i0:i1] += w * m
        den[i0:i1] += w
    out = np.full(t.size, np.nan)
    ok = den > 0
    out[ok] = num[ok] / den[ok]
    return out


def _uniform(times: np.ndarray, resid: np.ndarray) -> tuple[np.ndarray, float]:
    ok = np.isfinite(resid)
    t, r = times[ok], resid[ok]
    dt = float((t[-1] - t[0]) / (t.size - 1))
    grid = t[0] + dt * np.arange(t.size)
    return np.interp(grid, t, r), dt


def residual_spectrogram(times: np.ndarray, resid: np.ndarray, *,
                         nperseg_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Short-time amplitude spectrum of the residual (Hann segments, half overlap).

    The residual is first interpolated linearly to a uniform grid at its mean step
    (NaN samples dropped), so this is approximate for non-uniform stamps; the line list
    (:func:`residual_lines`) is the quantitative result.

    Parameters
    ----------
    times, resid : ndarray, shape (T,)
        Sample times in s and residual (record units, NaN allowed).
    nperseg_s : float
        Segment length in s.

    Returns
    -------
    f : ndarray, shape (F,)
        Frequencies in Hz.
    t : ndarray, shape (S,)
        Segment centre times in s (record time axis).
    amp : ndarray, shape (F, S)
        Amplitude (a sinusoid of amplitude A shows about A), record units.
    """
    t = np.asarray(times, dtype=float)
    r = np.asarray(resid, dtype=float)
    if np.count_nonzero(np.isfinite(r)) < 16:
        return np.zeros(0), np.zeros(0), np.zeros((0, 0))
    y, dt = _uniform(t, r)
    n = int(min(max(16, round(nperseg_s / dt)), y.size))
    f, ts, z = ssig.stft(y - y.mean(), fs=1.0 / dt, window="hann", nperseg=n,
                         noverlap=n // 2, boundary=None, padded=False, scaling="spectrum")
    # stft's 'spectrum' scaling gives A/2 for a sinusoid of amplitude A (one side).
    return f, ts + t[np.isfinite(r)][0], 2.0 * np.abs(z)


def label_line(freq: float, f1_range: tuple[float, float]) -> str:
    """Name a residual line: harmonic of f1, mains, or unexplained.

    Parameters
    ----------
    freq : float
        Line frequency in Hz.
    f1_range : (float, float)
        Smallest and largest mode-1 frequency in Hz seen in the record (f1 may change with
        amplitude; a harmonic matches ``n f`` for any f in the range, within 1 %).

    Returns
    -------
    str
        ``"<n>f1"`` (n = 2..5), ``"mains <f> Hz"`` / ``"mains <n>x<f> Hz"``, both joined
        by ``" or "`` when both match, or ``"unexplained"``.
    """
    lo, hi = f1_range
    names = [f"{n}f1" for n in range(2, HARMONICS + 1)
             if n * lo * (1 - HARMONIC_TOL) <= freq <= n * hi * (1 + HARMONIC_TOL)]
    for base in MAINS:
        n = max(1, round(freq / base))
        if abs(freq - n * base) <= MAINS_TOL:
            names.append(f"mains {base:g} Hz" if n == 1 else f"mains {n}x{base:g} Hz")
    return " or ".join(names) if names else "unexplained"


def residual_lines(times: np.ndarray, resid: np.ndarray, f1_range: tuple[float, float],
                   mode_ranges: Sequence[tuple[float, float]], *, factor: float = 5.0,
                   max_lines: int = 20, block: int = 512) -> tuple[ResidualLine, ...]:
    """Spectral lines of the residual that are not the fitted modes.

    The residual's periodogram (:func:`~bayesbeam.trials.modal_id.periodogram`, NaN
    samples dropped) is compared with its local median level: the median of blocks of
    1/``block`` of the spectrum, interpolated between block centres (robust to the
    lines themselves and follows a coloured noise floor). Local maxima above
    ``factor`` times that level, at least three unpadded frequency bins apart, are lines;
    those below 3/duration and within 2 % of a fitted mode's frequency range are left
    out (the fit's own leftovers), and the ``max_lines`` largest are kept.

    Parameters
    ----------
    times, resid : ndarray, shape (T,)
        Sample times in s and residual (record units, NaN allowed).
    f1_range : (float, float)
        Mode-1 frequency range in Hz (for the harmonic labels).
    mode_ranges : sequence of (float, float)
        Frequency range in Hz of each fitted mode.
    factor : float
        Threshold over the local median level. For white noise the periodogram's
        amplitude is Rayleigh distributed: it exceeds 5 times its median with
        probability e^{-17}, about 1e-3 false lines in a record of 1e5 samples.
    max_lines : int
        Most lines returned.
    block : int
        Number of blocks of the local median.

    Returns
    -------
    tuple of ResidualLine
        Sorted by frequency.
    """
    t = np.asarray(times, dtype=float)
    r = np.asarray(resid, dtype=float)
    ok = np.isfinite(r)
    if ok.sum() < 16:
        return ()
    f, amp = periodogram(t[ok], r[ok])
    nb = max(1, min(block, f.size // 32))
    edges = np.linspace(0, f.size, nb + 1).astype(int)
    med = np.array([np.median(amp[a:b]) for a, b in zip(edges[:-1], edges[1:], strict=True)])
    centres = 0.5 * (edges[:-1] + edges[1:])
    level = np.interp(np.arange(f.size), centres, med)
    dur = float(t[ok][-1] - t[ok][0])
    bins_per_unpadded = max(1, int(round(1.0 / (dur * (f[1] - f[0])))))
    peaks, _ = ssig.find_peaks(amp, height=factor * level, distance=3 * bins_per_unpadded)
    keep = []
    for i in peaks:
        fi = float(f[i])
        if fi < 3.0 / dur:
            continue
        if any(0.98 * lo <= fi <= 1.02 * hi for lo, hi in mode_ranges):
            continue
        keep.append(i)
    keep = sorted(keep, key=lambda i: -amp[i])[:max_lines]
    return tuple(ResidualLine(float(f[i]), float(amp[i]), float(amp[i] / level[i]),
                              label_line(float(f[i]), f1_range)) for i in sorted(keep))
