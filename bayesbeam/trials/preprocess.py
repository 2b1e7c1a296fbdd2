"""From a raw record to what a fit needs: the analysis start, end, rate, modes and offset.

A record as it comes off the acquisition holds more than the free vibration that the
model describes: a quiet stretch before the release or impact, the contact itself, tens
of thousands of non-uniform stamps at a rate far above the modes that carry the motion,
gaps in the stamps, a constant offset and, when the motion has decayed, seconds of
noise. :func:`plan` chooses what a fit uses and says why (a :class:`Preprocessing`
record, written to every JSON as ``preprocessing``); :func:`apply` does it. Every choice
can be fixed instead, by the trial file's ``[analysis]`` table
(:data:`~bayesbeam.trials.trial.ANALYSIS_KEYS`) or a command-line option.

The choices
-----------
1. **Start.** A trial that declares its initial state (``[initial] tip_deflection`` or
   ``tip_impulse``) starts where the trial says (its first sample, the state at ``t0``).
   Otherwise the release or impact is the sample farthest from the record's median
   (an acceleration record jumps to its largest value when the hand lets go or the
   hammer strikes; a displacement record starts its decay from its largest value) and
   the analysis starts :data:`SETTLE_S` after it: the contact of a hand or hammer lasts
   milliseconds to tens of milliseconds, and the sensor's anti-alias filter rings for
   tens of samples after the step (ISO 5348; Ewins, *Modal Testing*, 2000, §3.9).
2. **End.** The record's end, unless the motion has decayed into the noise before it:
   then the end of the last block (:data:`BLOCK_PERIODS` periods of mode 1, at least
   0.5 s) whose RMS about its mean exceeds :data:`END_SNR` noise standard deviations
   (the noise from :func:`bayesbeam.trials.noise.noise_floor` on the record's last
   block). Samples of pure noise tell the fit nothing about the beam.
3. **Modes and rate.** Mode 1 is the largest spectral peak within a factor 2 of the
   beam's nominal first frequency; mode k is sought at ``f1 r_k`` (``r_k`` the nominal
   beam's frequency ratios, which do not depend on E) within ±20 % and counts as seen
   when the largest ordinate there of a power spectrum (Hann window) exceeds
   :data:`~bayesbeam.trials.noise.PEAK_FACTOR` times the median ordinate within a
   factor 2 in frequency (the local floor: noise, leakage, the release's broadband
   content). The spectra are of the analysis span and of its first half, quarter, ...
   (down to :data:`MODE_PERIODS` periods of the mode); the one where the peak stands
   highest above its floor gives it (:func:`_mode_peak`), leaving out the ordinates
   within 1 % (:data:`~bayesbeam.trials.residual_lines.HARMONIC_TOL`, or the Hann
   window's main lobe ±2/T) of a harmonic ``n f1`` (``n >= 2``): a higher mode lives a
   fraction of a whole record, while harmonics of f1 (from a nonlinearity of the
   beam, its clamp, an attachment or the sensor) last as long as mode 1. They are
   listed (:attr:`Preprocessing.harmonics`); on the aluminium records they cluster
   around modes 2 and 3 (6-8 f1 and 13-17 f1 at 40 cm), where the resonances amplify
   them. Over the 20 s of the 40 cm aluminium records the
   largest peak near mode 2 (62 Hz, gone after ~1 s) was the line at 7 f1 = 66 Hz,
   and near mode 3 the one at 15 f1 = 141 Hz (the fitted model's mode 3 is at 164
   Hz); at 30 cm, 7 f1 = 114 Hz and 19 f1 = 310 Hz. A mode within 1 % of a harmonic
   is not told from it by the spectrum (the fits find it from the model's
   frequencies). When the motion ends before
   :data:`NOISE_TAIL` of the span (a long record,
   mostly noise), the spectrum is that of the span up to the end of the motion. The analysis
   band is ``1.25 ×`` the highest seen mode that fits the sample budget
   (:data:`MAX_SAMPLES` over the analysis span) and the record's own band, and never
   below ``1.25 ×`` the nominal beam's mode 2 (with mode 1 alone the rate is so low
   that the anti-alias filter's reach around the gaps of the aluminium stamps drops
   three quarters of the samples); the rate
   :data:`RATE_PER_BAND` (4) times the band (the anti-alias filter's pass band ends at
   the band, its stop band starts at the new Nyquist frequency). Modes above the band are
   removed from data (the anti-alias filter) and model (the sensor band) alike, so
   dropping one costs information, never correctness. Uniform stamps are decimated;
   non-uniform ones resampled (cubic spline, then the anti-alias filter), dropping
   every output that the filter would take across a gap longer than
   :data:`MAX_GAP_STEPS` median steps (the spline cannot bridge it: across a 5 ms gap
   it errs by ``(5/384)(2πfh)⁴`` = 2 times the amplitude of a 114 Hz mode, and its
   excursion through noisy end points grows as the fourth power of the gap). On the
   aluminium records this drops 30-50 % of the analysis samples.
   With the rate already within 10 % of the native one the raw stamps are kept.
4. **Initial state.** The declared one (``release``, ``impulse``), else free modal
   amplitudes of every model mode in the band (``modes:K``) at the first analysis
   sample (``t0`` is moved there).
5. **Offset.** A record without a declared initial state is a raw record: its constant
   offset (sensor zero, gravity on a tilted sensor) is fitted as a parameter
   (``offset``, the ``sensor_offset`` term). A trial with a declared state is taken as
   given (add ``sensor_offset`` to the model to fit one).

The sample budget
-----------------
The automatic rate keeps the analysis within the budget (:data:`MAX_SAMPLES`, or
``max_samples``). A record taken as it is (a declared initial state, or ``auto=False``)
keeps its own stamps, and a given rate is kept as given; when either would take more
samples than the budget, :func:`prepare` refuses with a :class:`PreprocessError` that
names the count and the fixes (a lower rate or a decimation factor, a window, or a
larger ``max_samples`` to accept the count) rather than applying the budget itself: a
trial taken as given is not resampled behind its user's back (its declared state holds
at ``t0`` at any rate, but the band, and with it the model, would change). The check
comes after :func:`plan` (about a second and a few hundred MB on 2 million samples) and
before any resampling or fit, whose memory grows with samples times walkers (a MAP
search on 2 million samples passed 6 GB within 100 s). :func:`plan` itself does not
refuse: ``bayesbeam inspect`` works on the raw stamps of any length.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from bayesbeam.physics.fem import assemble
from bayesbeam.trials.modal_id import periodogram
from bayesbeam.trials.noise import PEAK_FACTOR, noise_floor
from bayesbeam.trials.residual_lines import HARMONIC_TOL
from bayesbeam.trials.trial import BANDWIDTH_PER_RATE, Trial, TrialError

__all__ = [
    "END_SNR",
    "MAX_SAMPLES",
    "Preprocessing",
    "PreprocessError",
    "SETTLE_S",
    "apply",
    "nominal_f1",
    "plan",
    "prepare",
]

#: Time from the release or impact to the analysis start, s (see the module docstring).
SETTLE_S = 0.1
#: Most samples the analysis keeps by default (sets the rate on long records): a
#: viscous+kv posterior on 16k samples takes about 2 minutes on two cores.
MAX_SAMPLES = 16_384
#: A block counts as motion while its RMS exceeds this many noise standard deviations.
END_SNR = 3.0
#: Length of the blocks of the end test, in periods of mode 1.
BLOCK_PERIODS = 8.0
#: When the motion ends before this fraction of the span, the modes are sought on the
#: motion alone: a Hann window over a span that is mostly noise weights a decay at its
#: start by almost nothing (500 s with 10 s of motion: below 4e-4 over the decay), and
#: the largest of 10^5-10^6 noise ordinates in a mode's window then passes for its peak.
NOISE_TAIL = 0.5
#: Native steps longer than this many median steps are gaps (see :meth:`Trial.resample`).
MAX_GAP_STEPS = 4.0
#: Modes sought beyond the first (the nominal beam's ratios).
MAX_MODES = 8
#: Search half-width around f1 r_k, relative.
MODE_WINDOW = 0.2
#: Highest harmonic of mode 1 looked for (the preprocessing's report).
MAX_HARMONIC = 20
#: Shortest spectrum a higher mode is sought in, in periods of the mode (its resolution
#: 1/T is then 2 % of the mode's frequency, a tenth of the search window).
MODE_PERIODS = 50.0
#: The band edge above the highest kept mode.
BAND_MARGIN = 1.25
#: Analysis rate over analysis band: the anti-alias filter's transition band runs from
#: the band to the Nyquist frequency, half the band wide; a narrower one (2.56, the
#: analysers' convention) makes the filter, and its reach around each gap, 2.3 x longer.
RATE_PER_BAND = 4.0


class PreprocessError(ValueError):
    """The record cannot be prepared as asked; the message says what to change."""


@dataclass(frozen=True)
class Preprocessing:
    """What :func:`plan` chose for a record, and why (all times in s on the trial's axis).

    Attributes
    ----------
    start, end : float
        Analysis span in s.
    start_how, end_how : str
        How each was chosen.
    release : float or None
        Time of the detected release or impact, s (None: declared or given).
    rate : float or None
        Analysis sampling rate in Hz; None keeps the record's own stamps.
    band : float
        Analysis band in Hz (the sensor band the model applies).
    rate_how : str
        How the rate was chosen.
    f1 : float
        Mode-1 frequency seen in the record, Hz.
    modes_seen : tuple of float
        Frequencies (Hz) of the bending modes seen in the record, mode 1 first.
    mode_strength : tuple of float
        Their spectral peak over the median power within a factor 2 in frequency.
    mode_numbers : tuple of int
        Their mode numbers (1 for the first bending mode).
    modes_dropped : tuple of float
        Seen modes above the analysis band (removed from data and model), Hz.
    initial : str
        Initial condition of the fit ('release', 'impulse' or 'modes:K').
    initial_how : str
        Why.
    offset : str
        'fit' (a parameter ``offset``) or 'none'.
    offset_how : str
        Why.
    noise_sd : float
        Noise standard deviation of the record's last block (signal units, SI; free
        damped sinusoids removed, :func:`bayesbeam.trials.noise.noise_floor`); NaN when
        the block is too short. Sets the end of the motion.
    n_samples_in, n_samples : int
        Samples of the record and of the analysis.
    max_samples : int
        The sample budget used.
    given : tuple of str
        The choices fixed by the trial file or an option (not chosen here).
    loader : tuple of str
        What was done to the record before (``trial.source['processing']``).
    mode1_bins : int
        Bins of the (zero-padded) periodogram among which mode 1 was taken as the
        largest ordinate: sets the false-alarm threshold of the mode-1 line
        (:func:`bayesbeam.trials.checks.line_threshold`). 0: not recorded.
    harmonics : tuple of tuple
        Lines of the span's spectrum at harmonics of mode 1, ``(n, Hz, strength)`` for
        ``n = 2 .. MAX_HARMONIC`` below the record's band whose peak within 1 % of
        ``n f1`` exceeds ``PEAK_FACTOR`` times the floor (as for a mode): not bending
        modes (a nonlinearity of the beam, its clamp, an attachment or the sensor).
    """

    start: float
    end: float
    start_how: str
    end_how: str
    release: float | None
    rate: float | None
    band: float
    rate_how: str
    f1: float
    modes_seen: tuple[float, ...]
    mode_strength: tuple[float, ...]
    mode_numbers: tuple[int, ...]
    modes_dropped: tuple[float, ...]
    initial: str
    initial_how: str
    offset: str
    offset_how: str
    noise_sd: float
    n_samples_in: int
    n_samples: int
    max_samples: int
    given: tuple[str, ...]
    loader: tuple[str, ...]
    mode1_bins: int = 0
    harmonics: tuple[tuple[int, float, float], ...] = ()

    def to_json_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready dict (the ``preprocessing`` key of the outputs)."""
        out = dataclasses.asdict(self)
        for k in ("modes_seen", "mode_strength", "mode_numbers", "modes_dropped", "given",
                  "loader"):
            out[k] = list(out[k])
        out["harmonics"] = [{"n": n, "frequency": f, "strength": r}
                            for n, f, r in self.harmonics]
        out["units"] = "s for times, Hz for rate, band and frequencies"
        return out

    def model_name(self, name: str) -> str:
        """Return model ``name`` with ``+sensor_offset`` when the offset is fitted.

        Parameters
        ----------
        name : str
            A model name, e.g. 'viscous+kv'.

        Returns
        -------
        str
        """
        if self.offset == "fit" and "sensor_offset" not in name.split("+"):
            return f"{name}+sensor_offset"
        return name

    def lines(self) -> list[str]:
        """Return the choices as short lines for a person (printed on stderr)."""
        rate = "the record's own stamps" if self.rate is None else f"{self.rate:.1f} Hz"
        seen = ", ".join(f"{f:.1f}" for f in self.modes_seen) or "none"
        out = [
            f"analysis span {self.start:.4f}-{self.end:.4f} s ({self.start_how}; "
            f"end: {self.end_how})",
            f"rate {rate}, band {self.band:.1f} Hz ({self.rate_how}); modes seen at "
            f"{seen} Hz; {self.n_samples} of {self.n_samples_in} samples",
            f"initial condition {self.initial} ({self.initial_how})",
            f"offset: {self.offset} ({self.offset_how})",
        ]
        if self.harmonics:
            out.append("lines at harmonics of mode 1 (not bending modes: a nonlinearity of "
                       "the beam, clamp, an attachment or the sensor): " + ", ".join(
                           f"{n} f1 = {f:.1f} Hz" for n, f, _ in self.harmonics))
        if self.modes_dropped:
            out.append("modes above the band, left out of data and model: "
                       + ", ".join(f"{f:.1f} Hz" for f in self.modes_dropped))
        return out


# ------------------------------------------------------------------------------ helpers
def _declared_initial(trial: Trial) -> str | None:
    if "tip_deflection" in trial.initial:
        return "release"
    if "tip_impulse" in trial.initial:
        return "impulse"
    return None


def _ratios(trial: Trial) -> np.ndarray:
    """Nominal ratios f_k / f_1 of the trial's beam (rigid clamp; E cancels)."""
    fe = assemble(trial.beam, max(16, 2 * MAX_MODES), root_dof=False)
    lam = sla.eigh(fe.K, fe.M, eigvals_only=True, subset_by_index=[0, MAX_MODES - 1])
    return np.sqrt(lam / lam[0])


def nominal_f1(trial: Trial) -> float | None:
    """First natural frequency (Hz) of the trial's beam at its nominal E, or None.

    Rigid clamp, declared tip and point masses, 16 elements; None without a nominal E.

    Parameters
    ----------
    trial : Trial

    Returns
    -------
    float or None
    """
    if trial.beam.E is None:
        return None
    fe = assemble(trial.beam, 16, root_dof=False)
    lam = sla.eigh(fe.K, fe.M, eigvals_only=True, subset_by_index=[0, 0])
    return float(np.sqrt(lam[0] * trial.beam.E) / (2 * np.pi))


def _seen_modes(trial: Trial, t: np.ndarray, y: np.ndarray, band: float
                ) -> tuple[float, list[float], list[float], list[int], int, tuple]:
    """Return f1, the modes seen (Hz), their peak/floor ratios, mode numbers, f1's bins.

    Then the count of periodogram bins searched for mode 1, and the lines at harmonics
    of f1 (:attr:`Preprocessing.harmonics`).
    """
    f, amp = periodogram(t, y)
    power = amp**2
    f_lo = 3.0 / float(t[-1] - t[0])
    nominal = nominal_f1(trial)
    sel = (f > f_lo) & (f < band)
    if nominal is not None:
        sel &= (f > 0.5 * nominal) & (f < 2.0 * nominal)
    if not np.any(sel) and nominal is not None:
        # The nominal beam puts mode 1 outside what the record can show: a unit slip
        # (E not in Pa, lengths not in m, times not in s) rather than a span to choose.
        raise PreprocessError(
            f"the beam's nominal first frequency {nominal:.3g} Hz (from [beam] E and the "
            f"dimensions) is outside the record's spectrum ({f_lo:.3g}-"
            f"{min(band, float(f[-1])):.3g} Hz); check E (Pa), lengths (m), masses (kg), "
            "that the time column is in seconds, and that the analysis span ([analysis] "
            "start/end or --window) holds a few periods"
        )
    if not np.any(sel):
        raise PreprocessError(
            f"no spectrum to find mode 1 in (analysis {t[0]:.3f}-{t[-1]:.3f} s, band "
            f"{band:.1f} Hz); give the analysis span with [analysis] start/end or --window"
        )
    ratios = _ratios(trial)
    f1 = float(f[sel][np.argmax(power[sel])])
    seen, strength, numbers = [], [], []
    for k in range(ratios.size):
        fk = f1 * ratios[k]
        if fk * (1 - MODE_WINDOW) >= band:
            break
        win = (f > fk * (1 - MODE_WINDOW)) & (f < min(band, fk * (1 + MODE_WINDOW)))
        if not np.any(win):
            break
        if k == 0:
            local = (f > fk / 2) & (f < min(band, 2 * fk))
            i = int(np.argmax(np.where(win, power, -np.inf)))
            fp, ratio = float(f[i]), float(power[i] / np.median(power[local]))
        else:
            fp, ratio = _mode_peak(t, y, fk, band, f1)
        if k == 0 or ratio > PEAK_FACTOR:
            seen.append(fp)
            strength.append(ratio)
            numbers.append(k + 1)
    harmonics = []
    near = _near_harmonic(f, f1)
    for n in range(2, MAX_HARMONIC + 1):
        win = near & (np.rint(f / f1) == n)
        local = (f > n * f1 / 2) & (f < 2 * n * f1) & (f < band)
        if n * f1 * (1 + HARMONIC_TOL) >= band or np.count_nonzero(local) < 8:
            break
        i = int(np.argmax(np.where(win, power, -np.inf)))
        ratio = float(power[i] / np.median(power[local]))
        if ratio > PEAK_FACTOR:
            harmonics.append((n, float(f[i]), ratio))
    return f1, seen, strength, numbers, int(np.count_nonzero(sel)), tuple(harmonics)


def _near_harmonic(f: np.ndarray, f1: float, lobe: float = 0.0) -> np.ndarray:
    """Return where ``f`` (Hz) lies within ``max(HARMONIC_TOL n f1, lobe)`` of ``n f1``, n >= 2."""
    n = np.rint(f / f1)
    return (n >= 2) & (np.abs(f - n * f1) <= np.maximum(HARMONIC_TOL * n * f1, lobe))


def _mode_peak(t: np.ndarray, y: np.ndarray, fk: float, band: float, f1: float
               ) -> tuple[float, float]:
    """Return the peak (Hz) within ±MODE_WINDOW of ``fk`` and its height over the floor.

    Spectra of the span and of its first half, quarter, ... down to
    :data:`MODE_PERIODS` periods of ``fk``; the one where the peak stands highest
    above its floor (the median ordinate within a factor 2 in frequency) gives it. A
    decaying mode stands highest in a spectrum about as long as its decay time.
    Ordinates within ``HARMONIC_TOL`` of a harmonic ``n f1`` (n >= 2) are neither
    candidates nor floor: those lines last as long as mode 1 and outgrow a higher
    mode's peak in every spectrum long enough to resolve it.
    """
    best = (math.nan, -math.inf)
    dur = float(t[-1] - t[0])
    while True:
        m = t - t[0] <= dur * (1 + 1e-12)
        f, amp = periodogram(t[m], y[m])
        power = amp**2
        win = (f > fk * (1 - MODE_WINDOW)) & (f < min(band, fk * (1 + MODE_WINDOW)))
        local = (f > fk / 2) & (f < min(band, 2 * fk))
        harmonic = _near_harmonic(f, f1, lobe=2.0 / dur)  # the Hann main lobe: ±2/T
        win &= ~harmonic
        local &= ~harmonic
        if np.any(win) and np.count_nonzero(local) >= 8:
            i = int(np.argmax(np.where(win, power, -np.inf)))
            ratio = float(power[i] / np.median(power[local]))
            if ratio > best[1]:
                best = (float(f[i]), ratio)
        dur *= 0.5
        if dur * fk < MODE_PERIODS or np.count_nonzero(t - t[0] <= dur) < 64:
            return best


def _noise_sd(t: np.ndarray, y: np.ndarray, f1: float) -> tuple[float, float]:
    """Noise sd of the record's last block (free damped sinusoids removed) and the block (s)."""
    block = max(0.5, BLOCK_PERIODS / f1)
    last = t >= t[-1] - block
    if np.count_nonzero(last) < 64:
        return math.nan, block
    return float(noise_floor(t[last], y[last], max_modes=4).sd), block


def _motion_span(trial: Trial, t: np.ndarray, y: np.ndarray, span: np.ndarray
                 ) -> np.ndarray:
    """Return the part of ``span`` (a mask on ``t``) where the modes are sought.

    The span up to the end of the motion (:func:`_end_of_motion`, blocks of
    :data:`BLOCK_PERIODS` periods of the nominal mode 1, else 0.5 s) when that comes
    before :data:`NOISE_TAIL` of the span; else the whole span.
    """
    nominal = nominal_f1(trial)
    ts, ys = t[span], y[span]
    # Without a nominal E the blocks are 0.5 s (_noise_sd's shortest).
    sd, block = _noise_sd(ts, ys, nominal if nominal else math.inf)
    end, _ = _end_of_motion(ts, ys, sd, block)
    if end - ts[0] > NOISE_TAIL * (ts[-1] - ts[0]):
        return span
    return span & (t <= end)


def _end_of_motion(t: np.ndarray, y: np.ndarray, sd: float, block: float
                   ) -> tuple[float, str]:
    """End of the last block whose RMS exceeds END_SNR noise sd (see module doc)."""
    if t[-1] - t[0] < 3 * block:
        return float(t[-1]), "record end (too short to test for decay)"
    if not np.isfinite(sd):
        return float(t[-1]), "record end (too few samples to test for decay)"
    edges = np.arange(t[0], t[-1], block)
    idx = np.searchsorted(t, edges)
    idx = np.append(idx, t.size)
    rms = np.array([np.std(y[a:b]) if b - a > 1 else 0.0
                    for a, b in zip(idx[:-1], idx[1:], strict=True)])
    loud = np.flatnonzero(rms > END_SNR * sd)
    if loud.size == 0 or loud[-1] >= rms.size - 2:
        return float(t[-1]), f"record end (motion above {END_SNR:g} noise sd to the end)"
    end = float(t[min(idx[loud[-1] + 1], t.size - 1)])
    return end, (f"motion below {END_SNR:g} noise sd (noise sd {sd:.3g} from the last "
                 f"{block:.2f} s) after {end:.3f} s")


def _option(trial: Trial, given: dict[str, Any], key: str) -> Any:
    """Return the choice fixed by an option (``given``) or ``[analysis]``, else None."""
    if given.get(key) is not None:
        return given[key]
    return trial.analysis.get(key)


# ------------------------------------------------------------------------------ the plan
def plan(trial: Trial, **given: Any) -> Preprocessing:
    """Choose the analysis of a record (see the module docstring for each rule).

    Parameters
    ----------
    trial : Trial
        The record as read.
    **given
        Choices fixed by the caller (override the trial's ``[analysis]``, which
        overrides the rules): ``start``, ``end`` (s), ``rate`` (Hz), ``max_samples``,
        ``initial`` ('release' | 'impulse' | 'modes:K'), ``offset`` ('fit' | 'none'),
        ``auto`` (False: keep the record as it is, the trial's declared initial
        condition or 'release', no offset).

    Returns
    -------
    Preprocessing

    Raises
    ------
    PreprocessError
        For an unknown or out-of-range choice, or a span without samples.
    """
    unknown = sorted(set(given) - {"start", "end", "rate", "max_samples", "initial",
                                   "offset", "auto"})
    if unknown:
        raise PreprocessError(f"unknown preprocessing choices {unknown}")
    t = np.asarray(trial.times, dtype=float)
    y = np.asarray(trial.values, dtype=float)
    fixed = tuple(k for k in given if given[k] is not None) + tuple(
        k for k in trial.analysis if given.get(k) is None)
    declared = _declared_initial(trial)
    auto = _option(trial, given, "auto")
    if auto is None:  # a trial that declares its initial state is taken as given
        auto = declared is None
    off = ("trial with a declared initial state, taken as given" if declared and
           _option(trial, given, "auto") is None else "automatic choices off")
    budget = _option(trial, given, "max_samples") or MAX_SAMPLES
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 256:
        raise PreprocessError(f"max_samples must be an integer >= 256, got {budget!r}")
    native_band = trial.sensor_band

    # 1. start
    release = None
    start = _option(trial, given, "start")
    if start is not None:
        start_how = "given"
    elif not auto:
        start, start_how = float(t[0]), f"the trial's first sample ({off})"
    else:
        i = int(np.argmax(np.abs(y - np.median(y))))
        release = float(t[i])
        start = release + SETTLE_S
        start_how = (f"{SETTLE_S:g} s after the release/impact at {release:.4f} s "
                     "(largest |signal - median|)")
    start = float(start)
    # 2. end (needs f1: found on the span from the start)
    end = _option(trial, given, "end")
    span = t >= start if end is None else (t >= start) & (t <= float(end))
    if np.count_nonzero(span) < 64:
        raise PreprocessError(
            f"the analysis span from {start:.4f} s holds {np.count_nonzero(span)} samples "
            f"(record {t[0]:.4f}-{t[-1]:.4f} s); choose start/end inside the record"
        )
    # A record that is mostly noise after the motion: its modes are sought on the motion.
    search = span if end is not None else _motion_span(trial, t, y, span)
    f1, seen, strength, numbers, n_bins, harmonics = _seen_modes(trial, t[search], y[search],
                                                      native_band)
    noise_sd, block = _noise_sd(t[span], y[span], f1)
    if end is not None:
        end, end_how = float(end), "given"
    elif not auto:
        end, end_how = float(t[-1]), f"record end ({off})"
    else:
        end, end_how = _end_of_motion(t[span], y[span], noise_sd, block)
    if not end > start:
        raise PreprocessError(f"analysis end {end} s is not after its start {start} s")
    n_span = int(np.count_nonzero((t >= start) & (t <= end)))
    median_step = float(np.median(np.diff(t)))

    # 3. rate and band
    rate = _option(trial, given, "rate")
    cap = min(native_band, budget / (end - start) / RATE_PER_BAND)
    if rate is not None:
        rate = float(rate)
        if not 0 < rate < math.inf:
            raise PreprocessError(f"rate must be a positive finite number of Hz, got {rate!r}")
        band = min(native_band, BANDWIDTH_PER_RATE * rate)
        rate_how = "given"
    elif not auto:
        band, rate_how = native_band, f"the record's own ({off})"
    else:
        kept = [f for f in seen if BAND_MARGIN * f <= cap] or [seen[0]]
        # Never below mode 2 of the nominal beam: with mode 1 alone the rate falls to
        # 5 f1 and the anti-alias filter, as long in time as the rate is low, drops
        # every output it would take across one of the stamps' gaps: 410 of 1616
        # samples left on Al 30 cm #0 (82 Hz), where mode 2 is not seen.
        f2_nominal = f1 * float(_ratios(trial)[1])
        if BAND_MARGIN * f2_nominal <= cap:
            kept.append(f2_nominal)
        band = min(native_band, BAND_MARGIN * max(kept))
        rate = RATE_PER_BAND * band
        if trial.is_uniform:  # an integer decimation factor: no interpolation
            rate = 1.0 / (trial.dt * max(1, math.floor(1.0 / (rate * trial.dt))))
        rate_how = (f"{RATE_PER_BAND:g} x a band of {BAND_MARGIN:g} x the highest seen mode "
                    f"(at least the nominal mode 2) within the budget of {budget} samples "
                    f"and the record's band {native_band:.1f} Hz")
    if rate is not None and rate_how != "given" and rate >= 0.9 / median_step:
        rate, band = None, native_band
        rate_how += "; within 10 % of the native rate: raw stamps kept"
    dropped = tuple(f for f in seen if f > band)
    n_out = n_span if rate is None else int((end - start) * rate) + 1

    # 4. initial condition
    initial = _option(trial, given, "initial")
    ratios = _ratios(trial)
    n_modes = max(1, int(np.count_nonzero(f1 * ratios < band)))
    if initial is not None:
        initial_how = "given"
    elif declared is not None:
        initial, initial_how = declared, "declared in the trial's [initial]"
    elif not auto:
        initial, initial_how = "release", f"the default ({off})"
    else:
        initial = f"modes:{n_modes}"
        initial_how = (f"no declared initial state: free amplitudes of the {n_modes} model "
                       f"mode(s) below the band at the first analysis sample")
    # 5. offset
    offset = _option(trial, given, "offset")
    if offset is not None:
        if offset not in ("fit", "none"):
            raise PreprocessError(f"offset must be 'fit' or 'none', got {offset!r}")
        offset_how = "given"
    elif auto:
        offset = "fit"
        offset_how = "raw record: the constant offset is a parameter ('offset')"
    else:
        offset, offset_how = "none", off
    return Preprocessing(
        start=start, end=float(end), start_how=start_how, end_how=end_how, release=release,
        rate=rate, band=float(band), rate_how=rate_how, f1=f1, modes_seen=tuple(seen),
        mode_strength=tuple(strength), mode_numbers=tuple(numbers),
        modes_dropped=dropped, initial=str(initial), initial_how=initial_how,
        offset=str(offset), offset_how=offset_how, noise_sd=noise_sd,
        n_samples_in=int(t.size),
        n_samples=n_out, max_samples=int(budget), given=fixed,
        loader=tuple(str(s) for s in trial.source.get("processing", [])),
        mode1_bins=int(n_bins), harmonics=harmonics,
    )


def apply(trial: Trial, pre: Preprocessing) -> Trial:
    """Cut, resample and re-time a record as ``pre`` says.

    Parameters
    ----------
    trial : Trial
        The record as read (the one :func:`plan` saw).
    pre : Preprocessing

    Returns
    -------
    Trial
        The analysis record; with free modal amplitudes ``t0`` is its first sample.

    Raises
    ------
    PreprocessError
        When the span or the rate leaves too few samples.
    """
    t = np.asarray(trial.times)
    out = trial
    try:
        if pre.start > t[0] or pre.end < t[-1]:
            out = out.window(pre.start, pre.end)
        if pre.rate is not None:
            q = 1.0 / (pre.rate * out.dt)
            band = min(pre.band, 0.45 * pre.rate)  # a given rate may be below 2.2 x band
            if out.is_uniform and abs(q - round(q)) <= 1e-6 * q:
                out = out.decimate(max(1, round(q)), band=band)
            else:
                med = float(np.median(np.diff(out.times)))
                out = out.resample(1.0 / pre.rate, max_gap=MAX_GAP_STEPS * med, band=band)
    except TrialError as err:
        raise PreprocessError(f"cannot prepare {trial.name!r} as planned: {err}") from None
    # The modes seen on the raw stamps travel with the analysis record: estimates on a
    # resampled grid with holes are less reliable (the holes leak into any spectrum),
    # and the diagnosis starts its searches from them.
    seen = {str(k): f for k, f in zip(pre.mode_numbers, pre.modes_seen, strict=True)}
    out = dataclasses.replace(out, bandwidth=min(out.sensor_band, pre.band),
                              meta={**out.meta, "modes_seen_hz": seen})
    if pre.initial.startswith("modes:") and out.t0 < out.times[0]:
        t0 = float(out.times[0])
        source = dict(out.source)
        source["processing"] = [*source.get("processing", []),
                                f"t0 moved to the analysis start {t0!r} s (free modal state)"]
        out = dataclasses.replace(out, t0=t0, source=source)
    return out


def _check_budget(trial: Trial, given: dict[str, Any], pre: Preprocessing) -> None:
    """Refuse a count over the budget that the automatic rate did not choose."""
    if pre.n_samples <= pre.max_samples:
        return
    rate_given = _option(trial, given, "rate") is not None
    auto = _option(trial, given, "auto")
    if auto is None:
        auto = _declared_initial(trial) is None
    if auto and not rate_given:  # the plan's own rate (module docstring, choice 3)
        return
    span = pre.end - pre.start
    if rate_given:
        what = f"the given rate {pre.rate:.4g} Hz over {span:.4g} s"
    else:
        what = (f"the record's own stamps over {span:.4g} s, "
                + ("a trial with a declared initial state taken as given"
                   if _option(trial, given, "auto") is None else "automatic choices off"))
    max_rate = pre.max_samples / span
    unit = 10.0 ** (math.floor(math.log10(max_rate)) - 2)  # three digits, rounded down
    fixes = f"--rate {math.floor(max_rate / unit) * unit:g} or lower"
    if trial.is_uniform:
        fixes += f", --decimate {math.ceil(1.0 / (max_rate * trial.dt))} or more"
    raise PreprocessError(
        f"{trial.name!r}: the analysis would hold {pre.n_samples:,} samples ({what}), more "
        f"than the budget of {pre.max_samples:,}; a fit's memory and time grow with them "
        f"(gigabytes at millions): analyse fewer with {fixes} ([analysis] rate in the "
        "trial file), a shorter span (--window T0 T1), or accept them all with "
        f"--max-samples {pre.n_samples}"
    )


def prepare(trial: Trial, **given: Any) -> tuple[Trial, Preprocessing]:
    """Plan and apply in one call: the analysis record and the record of the choices.

    Parameters
    ----------
    trial : Trial
    **given
        As :func:`plan`.

    Returns
    -------
    tuple of (Trial, Preprocessing)
        ``Preprocessing.n_samples`` is the count of the prepared record.

    Raises
    ------
    PreprocessError
        As :func:`plan`, and for a record taken as given or a given rate that would
        analyse more samples than the budget (module docstring, "The sample budget").
    """
    pre = plan(trial, **given)
    _check_budget(trial, given, pre)
    out = apply(trial, pre)
    return out, dataclasses.replace(pre, n_samples=int(out.times.size))
