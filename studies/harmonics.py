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

For each record (raw, :func:`bayesbeam.trials.realdata.list_real_datasets`), on the span
``bayesbeam inspect`` analyses (:func:`bayesbeam.trials.preprocess.plan`: from 0.1 s after
the release to the end of the motion, raw stamps), with f1 the largest spectral peak
below 25 Hz, :func:`bayesbeam.trials.harmonics.second_harmonic` (also in ``bayesbeam
inspect``) fits windows of four mode-1 periods and gives the medians of ``C/A²`` and
``D/A²`` (1/(m/s²)) with their se, and the slope of the window means against the line (a
quadratic sensor predicts 1, the other two 0). The last column is the sensor height the
centripetal term would need.

Run: ``.venv/bin/python studies/harmonics.py [--records alu60-0,alu30-0]``.
"""

from __future__ import annotations

import argparse

import numpy as np

from bayesbeam.inference.problem import BETA1
from bayesbeam.trials.harmonics import second_harmonic
from bayesbeam.trials.modal_id import periodogram
from bayesbeam.trials.preprocess import plan
from bayesbeam.trials.realdata import list_real_datasets


def _mode1_ratio(length: float, sensor: float) -> float:
    """ψ1'(x)/ψ1(x) (1/m) of a uniform cantilever's first mode at the sensor."""
    k = (np.cosh(BETA1) + np.cos(BETA1)) / (np.sinh(BETA1) + np.sin(BETA1))
    b = BETA1 / length
    x = sensor
    psi = np.cosh(b * x) - np.cos(b * x) - k * (np.sinh(b * x) - np.sin(b * x))
    dpsi = b * (np.sinh(b * x) + np.sin(b * x) - k * (np.cosh(b * x) - np.cos(b * x)))
    return float(dpsi / psi)


def main(argv: list[str] | None = None) -> None:
    """Print the table of the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default=None, help="comma-separated labels (default all)")
    args = ap.parse_args(argv)
    want = None if args.records is None else set(args.records.split(","))
    print("| record | f1 Hz | windows | C/A² (1/(m/s²)) | D/A² | window means vs the line "
          "(a sensor: 1) | centripetal h needed |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for rec in list_real_datasets():
        label = rec.label
        if want is not None and label not in want:
            continue
        trial = rec.load(raw=True)
        pre = plan(trial)
        trial = trial.window(pre.start, pre.end)
        f, amp = periodogram(trial.times, trial.values)
        band = (f > 2.0) & (f < 25.0)
        f1 = float(f[band][np.argmax(amp[band])])
        sh = second_harmonic(trial.times, trial.values, f1)
        if sh is None:
            print(f"| {label} | {f1:.3f} | - | not measurable | | | |")
            continue
        ratio = _mode1_ratio(trial.beam.length, trial.beam.sensor_position)
        h = 2 * (2 * np.pi * sh.f1) ** 2 * sh.ratio / ratio**2
        h_text = f"{1e3 * h:.0f} mm" if abs(sh.ratio) > 2 * sh.ratio_se else "(no line)"
        print(f"| {label} | {sh.f1:.3f} | {int(sh.used.sum())} | {sh.ratio:.2e} ± "
              f"{sh.ratio_se:.1e} | {sh.quadrature_ratio:.1e} ± {sh.quadrature_ratio_se:.1e} | "
              f"{sh.mean_slope:.2f} ± {sh.mean_slope_se:.2f} | {h_text} |")


if __name__ == "__main__":
    main()
