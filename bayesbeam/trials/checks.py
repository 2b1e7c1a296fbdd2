"""Sanity checks of a record before sampling: whether it holds a beam's free decay.

A fit always returns numbers. Given a record that holds no motion, pure noise, or
stamps in the wrong unit, it returns confident nonsense, or fails deep inside with a
message about a prior's bound. These checks compare the record with what the beam
description and :func:`bayesbeam.trials.preprocess.plan` say, and return
:class:`~bayesbeam.physics.plausible.Finding` s (errors: refuse; warnings: say it):

Before the plan (:func:`record_checks`)
    * **constant signal** — every sample equal (an empty or wrong value column, a
      zero-filled export): an error naming the file, column and unit;
    * **declared sensor band** far above the stamps' Nyquist frequency (more than
      :data:`BAND_OVER_NYQUIST` times): a time column in ms read as s;
    * **nominal first frequency** (beam with a nominal E, rigid clamp,
      :func:`~bayesbeam.trials.preprocess.nominal_f1`) outside the record: at or above
      the record's band (the sensor band, at most the Nyquist frequency), or fewer than
      :data:`MIN_PERIODS` periods within the record. Either means mode 1 cannot be in
      the data as described: E not in Pa, lengths not in m, masses not in kg, or times
      not in s (a time column in ms divides the band by 1000).

After the plan (:func:`spectrum_checks`)
    * **no decaying oscillation** — the mode-1 line (``Preprocessing.mode_strength[0]``:
      largest periodogram ordinate among the ``n`` independent bins searched, over the
      median ordinate within a factor 2 in frequency) below :func:`line_threshold`;
    * **implied modulus** (a beam without a nominal E) — the E that puts the beam's
      first frequency on the record's mode 1 lies outside the plausible range of
      :data:`~bayesbeam.physics.plausible.PLAUSIBLE`: a unit slip in the time column,
      the lengths or the masses.

The false-alarm threshold of the mode-1 line
--------------------------------------------
For white noise each periodogram ordinate is a ``P Exp(1)`` variable (``P`` the mean
power), so the median ordinate is ``P ln 2`` and the ratio of an ordinate to the
median exceeds ``x / ln 2`` with probability ``e^-x``. The largest of ``n``
independent ordinates exceeds it with probability ``1 - (1 - e^-x)^n ≈ n e^-x``;
setting that to :data:`FALSE_ALARM` (1e-3) gives the threshold on the ratio::

    threshold = (ln n + ln(1 / FALSE_ALARM)) / ln 2,

at least :data:`~bayesbeam.trials.noise.PEAK_FACTOR` (20), the ratio at which every
other part of the package counts an ordinate as a peak. ``n`` is the number of bins of
the zero-padded periodogram searched (``Preprocessing.mode1_bins``), not the ``1/T``
-spaced independent ones: the padded grid's maxima between those bins raise the chance
of a large ordinate about as much as 4-5x more independent bins would. On 3000
white-noise records of 1280 and 5000 samples (the plan's search, ``n`` = 3180 and
12780) the threshold was exceeded in 0.10 % and 0.17 % of them; with the independent
count it was 0.4-0.5 %. The free decays of the shipped and public records stand at
5e5 to 1e8.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam.physics.plausible import PLAUSIBLE, Finding, plausibility
from bayesbeam.trials.noise import PEAK_FACTOR
from bayesbeam.trials.preprocess import Preprocessing, nominal_f1
from bayesbeam.trials.trial import _SI_UNIT, Trial

__all__ = [
    "BAND_OVER_NYQUIST",
    "FALSE_ALARM",
    "MIN_PERIODS",
    "check_trial",
    "line_threshold",
    "record_checks",
    "spectrum_checks",
]

#: False-alarm probability of the mode-1 line test on white noise (module docstring).
FALSE_ALARM = 1e-3
#: Fewest periods of the nominal mode 1 a record must span (the plan seeks mode 1 above
#: 3 / T, at no less than half the nominal frequency).
MIN_PERIODS = 1.5
#: A declared sensor band above this many times the stamps' Nyquist frequency is a
#: time unit slip (a real sensor aliasing its band onto the samples does so by a few
#: times at most; times in ms read as s give ~1000x).
BAND_OVER_NYQUIST = 100.0


def line_threshold(n_bins: int) -> float:
    """Least mode-1 line strength (peak over local median power) that is not noise.

    Parameters
    ----------
    n_bins : int
        Bins of the zero-padded periodogram searched for the line.

    Returns
    -------
    float
        ``max(PEAK_FACTOR, (ln n + ln(1/FALSE_ALARM)) / ln 2)`` (module docstring).
    """
    n = max(1, int(n_bins))
    return max(PEAK_FACTOR, (math.log(n) + math.log(1.0 / FALSE_ALARM)) / math.log(2.0))


def _where(trial: Trial) -> str:
    """Return the record's file, column and unit, as far as the trial knows them."""
    src = trial.source
    parts = []
    if src.get("file"):
        parts.append(str(Path(src["file"]).name))
    if src.get("value_column"):
        parts.append(f"column {src['value_column']!r}")
    if src.get("unit"):
        parts.append(f"unit {src['unit']!r}")
    return ", ".join(parts) if parts else f"trial {trial.name!r}"


def _nyquist(trial: Trial) -> tuple[float, float]:
    """Return the median step (s) and its Nyquist frequency (Hz)."""
    step = float(np.median(np.diff(trial.times)))
    return step, 0.5 / step


_SLIPS = ("check E (Pa), lengths (m) and masses (kg) in [beam], and that the time column "
          "is in seconds")


def record_checks(trial: Trial) -> list[Finding]:
    """Check a raw record for what needs no spectrum (see the module docstring).

    Parameters
    ----------
    trial : Trial
        The record as read (before :func:`~bayesbeam.trials.preprocess.plan`).

    Returns
    -------
    list of Finding
        Errors for a constant signal, a declared band far above the Nyquist frequency,
        or a nominal first frequency outside the record.
    """
    y = np.asarray(trial.values, dtype=float)
    out: list[Finding] = []
    scale = float(np.max(np.abs(y)))
    if float(np.ptp(y)) <= 1e-12 * scale or scale == 0.0:
        out.append(Finding(
            "error", "constant",
            f"the signal ({_where(trial)}) is constant (every value {y[0]:.6g} "
            f"{_SI_UNIT[trial.quantity]}): there is no motion to fit; check [signal] "
            "value_column and unit, and that the file holds the sensor's record"))
        return out  # no spectrum to test
    step, nyq = _nyquist(trial)
    span = float(trial.times[-1] - trial.times[0])
    bw = trial.bandwidth
    if bw is not None and math.isfinite(bw) and bw > BAND_OVER_NYQUIST * nyq:
        out.append(Finding(
            "error", "band",
            f"the declared sensor bandwidth {bw:.4g} Hz is {bw / nyq:.3g} x the Nyquist "
            f"frequency {nyq:.3g} Hz of the stamps (median step {step:.4g} s, record "
            f"{span:.4g} s long); is the time column in ms? times are in seconds"))
    f1 = nominal_f1(trial)
    if f1 is None:
        return out
    band = min(trial.sensor_band, nyq)
    if f1 >= band:
        out.append(Finding(
            "error", "nominal_f1",
            f"the beam's nominal first frequency {f1:.4g} Hz (E {trial.beam.E:.3g} Pa) is "
            f"above the record's band {band:.4g} Hz (sensor band / Nyquist frequency, "
            f"median step {step:.4g} s): mode 1 cannot be in the data; {_SLIPS} (a time "
            "column in ms gives a band 1000 x too low)"))
    elif f1 * span < MIN_PERIODS:
        out.append(Finding(
            "error", "nominal_f1",
            f"the record spans {span:.4g} s, {f1 * span:.2g} periods of the beam's nominal "
            f"first frequency {f1:.4g} Hz (E {trial.beam.E:.3g} Pa); at least "
            f"{MIN_PERIODS:g} are needed to see mode 1; {_SLIPS}"))
    return out


def spectrum_checks(trial: Trial, pre: Preprocessing,
                    ranges: Mapping[str, Any] | None = None) -> list[Finding]:
    """Check the record against what the plan found (see the module docstring).

    Parameters
    ----------
    trial : Trial
        The record as :func:`~bayesbeam.trials.preprocess.plan` saw it.
    pre : Preprocessing
        Its plan.
    ranges : mapping, optional
        Overrides of :data:`~bayesbeam.physics.plausible.PLAUSIBLE` (``E`` is used).

    Returns
    -------
    list of Finding
        An error when the mode-1 line is not above white noise's false-alarm level, or
        when the E it implies (beam without a nominal E) is implausible.
    """
    out: list[Finding] = []
    strength = pre.mode_strength[0] if pre.mode_strength else 0.0
    # Without the count (a record of an older plan): 8 padded bins per 1/T over the band.
    n_bins = pre.mode1_bins or max(1, round(8 * pre.band * (pre.end - pre.start)))
    limit = line_threshold(n_bins)
    if not strength >= limit:
        out.append(Finding(
            "error", "mode_line",
            f"no decaying oscillation in the record ({_where(trial)}): its strongest line "
            f"near mode 1 ({pre.f1:.4g} Hz) is {strength:.3g} x the local median power, "
            f"below the {limit:.3g} x that white noise exceeds with probability at most "
            f"{FALSE_ALARM:g} ({n_bins} bins searched): the record looks like noise; "
            "check [signal] value_column, unit "
            "and the analysis span ([analysis] start/end or --window)"
            + ("" if trial.beam.E is None else ", and E and the dimensions in [beam], "
               "which put mode 1 near the nominal frequency")))
        return out  # an implied E from noise would say nothing more
    if trial.beam.E is not None:
        return out
    lo, hi = (dict(PLAUSIBLE) | dict(ranges or {}))["E"]
    unit_beam = trial.beam.replace(E=1.0)
    f_unit = nominal_f1(dataclasses.replace(trial, beam=unit_beam))
    if f_unit is None or not f_unit > 0:  # pragma: no cover - E = 1 Pa always gives one
        return out
    E = (pre.f1 / f_unit) ** 2
    if lo <= E <= hi:
        return out
    step, _ = _nyquist(trial)
    side = (f"below the softest elastomers ({lo:.3g} Pa)" if E < lo
            else f"above the stiffest solid (diamond, {hi:.3g} Pa)")
    out.append(Finding(
        "error", "implied_E",
        f"the record's mode 1 at {pre.f1:.4g} Hz implies E = {E:.3g} Pa for this beam, "
        f"{side}; check that the time column is in seconds (the record spans "
        f"{float(trial.times[-1] - trial.times[0]):.4g} s, median step {step:.4g} s), "
        "lengths (m) and masses (kg) in [beam], or give the nominal E in [beam]"))
    return out


def check_trial(trial: Trial, pre: Preprocessing | None = None,
                ranges: Mapping[str, Any] | None = None) -> list[Finding]:
    """All checks before sampling: the beam's plausibility and the record's.

    The command line (``bayesbeam fit``, ``compare``, ``diagnose``) runs these through
    :func:`bayesbeam.cli.options.prepare_trial`; :func:`bayesbeam.inference.fit.fit`
    does not, so call this first on records from elsewhere.

    Parameters
    ----------
    trial : Trial
        The record as read (before preprocessing).
    pre : Preprocessing, optional
        Its plan (:func:`~bayesbeam.trials.preprocess.plan`); without it the spectral
        checks are skipped.
    ranges : mapping, optional
        Overrides of :data:`~bayesbeam.physics.plausible.PLAUSIBLE`.

    Returns
    -------
    list of Finding
        Errors and warnings, beam first; empty when all is plausible.
    """
    out = plausibility(trial.beam, ranges) + record_checks(trial)
    if pre is not None and not any(f.check == "constant" for f in out):
        out += spectrum_checks(trial, pre, ranges)
    return out
