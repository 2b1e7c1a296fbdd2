"""Study: the line at twice f1 in the measured records, and what can make it.

The residuals of the aluminium records keep lines at harmonics of mode 1 that no cause of
the catalogue produced (README, "Whole-record diagnoses"). An even harmonic needs a
nonlinearity that is even in the motion. Three candidates predict different things for a
record whose mode 1 is ``a(t) = A cos ψ`` at the sensor (acceleration), ``ψ = ωt + φ``:

* a quadratic sensor (the catalogue's ``sensor_quadratic``, reading ``a + k2 a²``): a
  line ``(k2 A²/2) cos 2ψ`` in phase with ``cos 2ψ`` **and a mean shift** ``k2 A²/2`` of
  the same size, decaying with ``A²``;
* a quadratic restoring force on mode 1 (an asymmetric stiffness: a pre-curved strip,
  an asymmetric clamp): the forced second harmonic, also in phase with ``cos 2ψ`` (for
  light damping) and growing as ``A²``, but **no mean acceleration** (its mean is a
  static deflection);
* the sensor's kinematics on the rotating strip (centripetal ``-h θ'²`` of a sensor at
  height ``h`` above the neutral axis; gravity is not along the sensing axis in these
  records, PROVENANCE.md): in phase, no mean shift either, with
  ``h = 2 ω² (C/A²) / r²``, ``r = ψ1'(x_s)/ψ1(x_s)`` the first mode's slope over its
  deflection at the sensor (uniform cantilever), which must come out at a few mm.

For each record (raw, :func:`bayesbeam.trials.realdata.list_real_datasets`), resampled
to 1 kHz by linear interpolation (the lines studied are below 60 Hz), windows of four
mode-1 periods from 0.3 s after the release are fitted by least squares with
``e^{-σt}(a cos ωt + b sin ωt) + e^{-2σt}(c cos 2ωt + d sin 2ωt) + o``. The second
harmonic ``(c, d)`` is written in the frame of ``2ψ``: ``C`` in phase, ``D`` in
quadrature. Over the windows whose mode-1 amplitude is above 5 % of the largest, it
prints the medians of ``C/A²`` and ``D/A²`` (1/(m/s²)), the slope of the window
offsets against ``C`` (a quadratic sensor predicts 1, the other two 0; least squares with
its se), and the sensor height the kinematics would need.

Run: ``.venv/bin/python studies/harmonics.py [--records alu60-0,alu30-0]``.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.optimize import least_squares

from bayesbeam.trials.realdata import ENES, list_real_datasets

BETA1 = 1.875104069
RATE = 1000.0
PERIODS = 4


def _label(rec) -> str:
    if rec.dataset == ENES:
        return f"alu{rec.kwargs['length_cm']}-{rec.kwargs['index']}"
    return "steel"


def _mode1_ratio(length: float, sensor: float) -> float:
    """ψ1'(x)/ψ1(x) (1/m) of a uniform cantilever's first mode at the sensor."""
    k = (np.cosh(BETA1) + np.cos(BETA1)) / (np.sinh(BETA1) + np.sin(BETA1))
    b = BETA1 / length
    x = sensor
    psi = np.cosh(b * x) - np.cos(b * x) - k * (np.sinh(b * x) - np.sin(b * x))
    dpsi = b * (np.sinh(b * x) + np.sin(b * x) - k * (np.cosh(b * x) - np.cos(b * x)))
    return float(dpsi / psi)


def windows(t: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """Return f1 (Hz) and rows (start s, A, C, D, offset) of the windowed fits."""
    tt = np.arange(t[0], t[-1], 1.0 / RATE)
    yy = np.interp(tt, t, y)
    i0 = int(np.argmax(np.abs(yy[: int(3 * RATE)]))) + int(0.3 * RATE)
    seg = yy[i0: i0 + int(8 * RATE)]
    seg = seg - seg.mean()
    f = np.fft.rfftfreq(16 * seg.size, 1.0 / RATE)
    spec = np.abs(np.fft.rfft(seg * np.hanning(seg.size), 16 * seg.size))
    band = (f > 2.0) & (f < 25.0)
    f1 = float(f[band][np.argmax(spec[band])])
    width = PERIODS / f1
    rows = []
    for s0 in np.arange(tt[i0], tt[-1] - width, width):
        m = (tt >= s0) & (tt < s0 + width)
        x, z = tt[m] - s0, yy[m]

        def res(p, x=x, z=z):
            w, sg, a, b, c, d, o = p
            e = np.exp(-sg * x)
            return (e * (a * np.cos(w * x) + b * np.sin(w * x))
                    + e**2 * (c * np.cos(2 * w * x) + d * np.sin(2 * w * x)) + o - z)

        a0 = float(np.std(z) * np.sqrt(2))
        fit = least_squares(res, [2 * np.pi * f1, 0.1, a0, 0.0, 0.0, 0.0, float(np.mean(z))],
                            x_scale=[1, 0.1, a0, a0, 1e-3 * a0, 1e-3 * a0, a0])
        _, _, a, b, c, d, o = fit.x
        amp, phi = np.hypot(a, b), np.arctan2(-b, a)  # a cos + b sin = A cos(wx + φ)
        big_c = c * np.cos(2 * phi) - d * np.sin(2 * phi)
        big_d = c * np.sin(2 * phi) + d * np.cos(2 * phi)
        rows.append((s0, amp, big_c, big_d, o))
    return f1, np.array(rows)


def summary(rec, f1: float, rows: np.ndarray) -> dict[str, float]:
    """Return the record's row of the table (module docstring)."""
    sel = rows[:, 1] > 0.05 * rows[:, 1].max()
    A, C, D, o = rows[sel, 1], rows[sel, 2], rows[sel, 3], rows[sel, 4]
    o = o - np.median(rows[-5:, 4])  # offsets relative to the record's quiet end
    X = np.column_stack([np.ones_like(C), C])
    coef, *_ = np.linalg.lstsq(X, o, rcond=None)
    r = o - X @ coef
    cov = np.linalg.inv(X.T @ X) * float(r @ r) / max(1, r.size - 2)
    beam = rec.load(raw=True).beam
    ratio = _mode1_ratio(beam.length, beam.sensor_position)
    c_a2 = float(np.median(C / A**2))
    return {"f1": f1, "windows": int(sel.sum()), "C/A2": c_a2,
            "D/A2": float(np.median(D / A**2)), "offset_slope": float(coef[1]),
            "offset_slope_se": float(np.sqrt(cov[1, 1])),
            "h_mm": 1e3 * 2 * (2 * np.pi * f1) ** 2 * c_a2 / ratio**2}


def main(argv: list[str] | None = None) -> None:
    """Print the table of the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default=None, help="comma-separated labels (default all)")
    args = ap.parse_args(argv)
    want = None if args.records is None else set(args.records.split(","))
    print("| record | f1 Hz | windows | median C/A² | median D/A² | offset vs C (sensor: 1) "
          "| centripetal h needed |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for rec in list_real_datasets():
        label = _label(rec)
        if want is not None and label not in want:
            continue
        trial = rec.load(raw=True)
        f1, rows = windows(trial.times, trial.values)
        s = summary(rec, f1, rows)
        print(f"| {label} | {s['f1']:.3f} | {s['windows']} | {s['C/A2']:.2e} | "
              f"{s['D/A2']:.2e} | {s['offset_slope']:.2f} ± {s['offset_slope_se']:.2f} | "
              f"{s['h_mm']:.0f} mm |")


if __name__ == "__main__":
    main()
