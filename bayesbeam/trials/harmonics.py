"""The second harmonic of mode 1 in a record: its phase, its growth, and the window means.

A line at twice f1 needs a nonlinearity that is even in the motion. Three kinds make
one, and they differ in what else they make (``a = A cos ψ`` the first mode at the
sensor, ``ψ = ωt + φ``):

* a sensor whose reading is quadratic (``a + k2 a²``, the catalogue's
  ``sensor_quadratic``): the line ``(k2 A²/2) cos 2ψ``, in phase with ``cos 2ψ``, and a
  shift of the mean by ``k2 A²/2``, as large as the line;
* a quadratic restoring force on mode 1 (an asymmetric stiffness) or the sensor's
  kinematics on the rotating beam (centripetal ``-h θ'²``): the same line, in phase for
  light damping, but no mean acceleration (a bounded motion's acceleration has zero
  mean); their size per ``A²`` changes with the frequency (as ``1/ω⁴`` and ``1/ω²``),
  a sensor's does not.

:func:`second_harmonic` fits, in windows of a few mode-1 periods on the record's own
stamps, ``e^{-σx}(a cos ωx + b sin ωx) + e^{-2σx}(c cos 2ωx + d sin 2ωx) + o`` (x the
time from the window's start) by nonlinear least squares, writes the harmonic in the
frame of ``2ψ`` (``C`` in phase, ``D`` in quadrature) and summarises the windows whose
mode-1 amplitude is above a fraction of the largest: the medians of ``C/A²`` and
``D/A²`` with their se, and the slope of the window offsets ``o`` against ``C`` times
the mean of ``e^{-2σx}`` over the window (least squares with a constant): 1 for a
quadratic sensor, 0 for the other two. Other modes in
a window are not fitted; they only add to its residual (mode 2 of a cantilever sits at
6.3 f1 or more, far from 2 f1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from bayesbeam._util import finite_or_none

__all__ = ["SecondHarmonic", "harmonic_text", "second_harmonic"]

#: Asymptotic se of a median of n normal values, in units of sd / sqrt(n).
_MEDIAN_SE = math.sqrt(math.pi / 2)


@dataclass(frozen=True)
class SecondHarmonic:
    """The second harmonic of mode 1, window by window (module docstring).

    Attributes
    ----------
    f1 : float
        First frequency used (Hz).
    start_s, amplitude, in_phase, quadrature, offset : ndarray, shape (n,)
        Per window: start (s), mode-1 amplitude A, the harmonic's parts C and D in the
        frame of twice mode 1's phase, and the offset o (signal units).
    used : ndarray of bool, shape (n,)
        Windows in the summary (amplitude above ``min_fraction`` of the largest).
    ratio, ratio_se : float
        Median of ``C/A²`` and its se (1/signal unit).
    quadrature_ratio, quadrature_ratio_se : float
        Median of ``D/A²`` and its se.
    mean_slope, mean_slope_se : float
        Slope of the offsets against ``C``: 1 for a quadratic sensor, 0 for a
        quadratic force or the sensor's kinematics.
    """

    f1: float
    start_s: np.ndarray
    amplitude: np.ndarray
    in_phase: np.ndarray
    quadrature: np.ndarray
    offset: np.ndarray
    used: np.ndarray
    ratio: float
    ratio_se: float
    quadrature_ratio: float
    quadrature_ratio_se: float
    mean_slope: float
    mean_slope_se: float

    def to_json_dict(self) -> dict[str, Any]:
        """Return the summary and the per-window values as JSON-serialisable types."""
        return {
            "f1_hz": finite_or_none(self.f1),
            "n_windows": int(self.used.sum()),
            "in_phase_per_amplitude2": finite_or_none(self.ratio),
            "in_phase_per_amplitude2_se": finite_or_none(self.ratio_se),
            "quadrature_per_amplitude2": finite_or_none(self.quadrature_ratio),
            "quadrature_per_amplitude2_se": finite_or_none(self.quadrature_ratio_se),
            "mean_vs_in_phase_slope": finite_or_none(self.mean_slope),
            "mean_vs_in_phase_slope_se": finite_or_none(self.mean_slope_se),
            "windows": {k: [finite_or_none(float(v)) for v in getattr(self, k)]
                        for k in ("start_s", "amplitude", "in_phase", "quadrature", "offset")},
        }

    def text(self) -> str:
        """One line for a reader (:func:`harmonic_text`)."""
        return harmonic_text(self.to_json_dict())


def harmonic_text(record: dict[str, Any]) -> str:
    """One line for a reader: the harmonic and what the window means say.

    Parameters
    ----------
    record : dict
        :meth:`SecondHarmonic.to_json_dict` (as written to ``inspect.json``).

    Returns
    -------
    str
    """
    def f(key: str, spec: str) -> str:
        v = record.get(key)
        return "n/a" if v is None else format(v, spec)

    f1 = record.get("f1_hz")
    where = "n/a" if f1 is None else f"{2 * f1:.2f} Hz"
    head = (f"second harmonic of mode 1 ({where}, {record.get('n_windows', 0)} windows): in "
            f"phase {f('in_phase_per_amplitude2', '.3g')} ± "
            f"{f('in_phase_per_amplitude2_se', '.2g')}, quadrature "
            f"{f('quadrature_per_amplitude2', '.3g')} ± "
            f"{f('quadrature_per_amplitude2_se', '.2g')} per signal unit, times A²")
    c, c_se = record.get("in_phase_per_amplitude2"), record.get("in_phase_per_amplitude2_se")
    if c is None or c_se is None or not abs(c) > 2 * c_se:
        return head + ": no line beyond 2 se, so the window means test nothing"
    return (head + f"; window means against it: slope {f('mean_vs_in_phase_slope', '.2f')} "
            f"± {f('mean_vs_in_phase_slope_se', '.2f')} (a quadratic sensor gives 1, a "
            "quadratic force or the sensor's motion 0)")


def _fit_window(x: np.ndarray, z: np.ndarray, f1: float) -> np.ndarray:
    """Least-squares (ω, σ, a, b, c, d, o) of one window (module docstring)."""
    a0 = float(np.std(z) * math.sqrt(2.0)) or 1.0

    def res(p: np.ndarray) -> np.ndarray:
        w, sg, a, b, c, d, o = p
        e = np.exp(-sg * x)
        return (e * (a * np.cos(w * x) + b * np.sin(w * x))
                + e * e * (c * np.cos(2 * w * x) + d * np.sin(2 * w * x)) + o - z)

    p0 = np.array([2 * math.pi * f1, 0.0, a0, 0.0, 0.0, 0.0, float(np.mean(z))])
    scale = np.array([1.0, 0.1, a0, a0, 1e-3 * a0, 1e-3 * a0, a0])
    return least_squares(res, p0, x_scale=scale).x


def second_harmonic(times: np.ndarray, values: np.ndarray, f1: float, *,
                    periods: float = 4.0, min_fraction: float = 0.05,
                    ) -> SecondHarmonic | None:
    """Measure the second harmonic of mode 1 window by window (module docstring).

    Parameters
    ----------
    times : ndarray, shape (T,)
        Stamps in s, increasing (need not be uniform).
    values : ndarray, shape (T,)
        The record in its SI unit, from after the release or impact.
    f1 : float
        First frequency in Hz (> 0), e.g. from :func:`bayesbeam.trials.amplitude.
        amplitude_curves`.
    periods : float
        Window length in mode-1 periods.
    min_fraction : float
        Windows whose mode-1 amplitude is below this fraction of the largest are fitted
        but left out of the summary (their harmonic is below the noise).

    Returns
    -------
    SecondHarmonic or None
        None when fewer than three windows are summarised.
    """
    t = np.asarray(times, dtype=float)
    y = np.asarray(values, dtype=float)
    if not (math.isfinite(f1) and f1 > 0):
        return None
    width = periods / f1
    rows = []
    for s0 in np.arange(t[0], t[-1] - width, width):
        m = (t >= s0) & (t < s0 + width)
        if m.sum() < 16:  # fewer samples than a window's seven parameters need
            continue
        x = t[m] - s0
        _, sg, a, b, c, d, o = _fit_window(x, y[m], f1)
        amp, phi = math.hypot(a, b), math.atan2(-b, a)  # a cos + b sin = A cos(ωx + φ)
        # The harmonic's size at the window's start decays as e^{-2σx} within it; the
        # mean shift a quadratic sensor adds decays alike, and the constant o takes its
        # average over the window: compare o with C times that average.
        env = float(np.mean(np.exp(-2.0 * sg * x)))
        rows.append((s0, amp, c * math.cos(2 * phi) - d * math.sin(2 * phi),
                     c * math.sin(2 * phi) + d * math.cos(2 * phi), o, env))
    if not rows:
        return None
    s0, amp, big_c, big_d, off, env = (np.array(v) for v in zip(*rows, strict=True))
    used = amp > min_fraction * amp.max()
    n = int(used.sum())
    if n < 3:
        return None
    rc, rd = big_c[used] / amp[used] ** 2, big_d[used] / amp[used] ** 2
    X = np.column_stack([np.ones(n), big_c[used] * env[used]])
    coef, *_ = np.linalg.lstsq(X, off[used], rcond=None)
    r = off[used] - X @ coef
    cov = np.linalg.pinv(X.T @ X) * float(r @ r) / max(n - 2, 1)
    return SecondHarmonic(
        f1=float(f1), start_s=s0, amplitude=amp, in_phase=big_c, quadrature=big_d,
        offset=off, used=used,
        ratio=float(np.median(rc)), ratio_se=_MEDIAN_SE * float(np.std(rc)) / math.sqrt(n),
        quadrature_ratio=float(np.median(rd)),
        quadrature_ratio_se=_MEDIAN_SE * float(np.std(rd)) / math.sqrt(n),
        mean_slope=float(coef[1]), mean_slope_se=math.sqrt(max(float(cov[1, 1]), 0.0)),
    )
