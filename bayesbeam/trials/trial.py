"""Measured or simulated trials: a sensor time series plus the beam it came from.

This module holds the in-memory record, :class:`Trial`, with its units
(:data:`UNITS`, :func:`unit_factor`) and validation. Trial files (a small TOML file
that points at a CSV file, format in ``data/README.md``) are read and written by
:mod:`bayesbeam.trials.io`.

Values are converted to SI units when read, so a :class:`Trial` always holds SI
values. Time stamps need not be uniform, but they must be strictly increasing.

Time origin: times are kept as given (they are not shifted to start at zero). The
instant at which a model's initial condition applies is :attr:`Trial.t0`; it
defaults to ``times[0]``, and :meth:`Trial.window`, :meth:`Trial.decimate` and
:meth:`Trial.resample` keep it, so a release at ``t0`` stays the same physical
instant after the data are cut (a forward model evaluates at ``times - t0``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.interpolate
import scipy.signal

from bayesbeam.physics.beam import QUANTITIES, Beam

__all__ = [
    "BANDWIDTH_PER_RATE",
    "STANDARD_GRAVITY",
    "UNIFORM_RTOL",
    "UNITS",
    "Trial",
    "TrialError",
    "unit_factor",
]

#: Standard gravity in m/s^2 (CGPM 1901), used to convert the unit 'g'.
STANDARD_GRAVITY = 9.80665

#: unit -> (quantity, factor to SI). Values in the unit times the factor give SI values.
UNITS: dict[str, tuple[str, float]] = {
    "m": ("displacement", 1.0),
    "mm": ("displacement", 1e-3),
    "m/s": ("velocity", 1.0),
    "mm/s": ("velocity", 1e-3),
    "m/s^2": ("acceleration", 1.0),
    "g": ("acceleration", STANDARD_GRAVITY),
}

_SI_UNIT = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}

#: Time stamps count as uniform when every step is within this fraction of the mean
#: step. Jitter of 0.1 % of the step moves the phase of a component at frequency f by at
#: most 2 pi f 1e-3 dt, i.e. < 0.004 rad below the Nyquist frequency; LabVIEW-style
#: stamps rounded to 1 us at ~1.6 kHz sampling (0.17 % jitter) should be regenerated.
UNIFORM_RTOL = 1e-3

#: Default sensor bandwidth as a fraction of the sampling rate, 1/2.56: the anti-alias
#: convention of dynamic signal analysers (an analyser sampling at fs shows fs/2.56 Hz,
#: e.g. 400 lines from 1024 samples) and about the pass band of the decimation filters of
#: delta-sigma converters (0.39-0.45 fs). Content between this and fs/2 is in the filter's
#: transition band, neither passed nor stopped reliably.
BANDWIDTH_PER_RATE = 1 / 2.56

#: Stop-band attenuation of the decimation filter, dB (:func:`anti_alias_taps`).
ANTI_ALIAS_DB = 100.0

_INITIAL_KEYS = {"tip_deflection": "m", "tip_impulse": "N s", "note": None}

#: Keys of ``[analysis]`` (choices of :mod:`bayesbeam.trials.preprocess` a trial file may
#: fix) and the type each takes: ``start``/``end`` in s on the trial's time axis,
#: ``rate`` in Hz, ``max_samples`` a count, ``initial`` 'release' | 'impulse' |
#: 'modes:K', ``offset`` 'fit' | 'none', ``auto`` false to switch the automatic choices off.
ANALYSIS_KEYS: dict[str, tuple[type, ...]] = {
    "start": (int, float), "end": (int, float), "rate": (int, float),
    "max_samples": (int,), "initial": (str,), "offset": (str,), "auto": (bool,),
}


def anti_alias_taps(q: int, edge: float = BANDWIDTH_PER_RATE) -> np.ndarray:
    """Zero-phase FIR low-pass for decimation by ``q`` (Kaiser window, Kaiser 1974).

    Pass band up to ``edge`` times the new rate (default :data:`BANDWIDTH_PER_RATE`:
    ripple ``10^(-ANTI_ALIAS_DB/20)``), stop band from the new Nyquist frequency with
    :data:`ANTI_ALIAS_DB` attenuation, so that what folds into the new band is
    1e-5 of what lies above it. (scipy.signal.decimate's default FIR, a Hamming window
    of 20 q + 1 taps, stops only ~50 dB: an impact record's higher modes, tens of
    m/s^2, would fold back at ~0.1 m/s^2, far above an accelerometer's noise.) The
    filter's length is inversely proportional to its transition band: a band of 1/4 of
    the new rate gives a filter 2.3 times shorter than 1/2.56, which matters where its
    reach around gaps in the stamps costs samples (:meth:`Trial.resample`).

    Parameters
    ----------
    q : int
        Decimation factor >= 2.
    edge : float
        Pass-band edge as a fraction of the new rate, in (0, 0.5).

    Returns
    -------
    ndarray, shape (n,)
        Taps (odd n, symmetric, unit DC gain), at the input rate.
    """
    if not 0 < edge < 0.5:
        raise TrialError(f"the pass band must end below the new Nyquist frequency; got "
                         f"{edge} of the new rate")
    e = 2 * edge / q  # pass-band edge, in units of the input Nyquist frequency
    numtaps, beta = scipy.signal.kaiserord(ANTI_ALIAS_DB, 1.0 / q - e)
    numtaps |= 1
    return scipy.signal.firwin(numtaps, 0.5 * (e + 1.0 / q), window=("kaiser", beta))


class TrialError(ValueError):
    """A trial (file or record) is invalid; the message says what and how to fix it."""


def _edge(band: float | None, new_dt: float) -> float:
    """Pass-band edge as a fraction of the new rate (default BANDWIDTH_PER_RATE)."""
    if band is None:
        return BANDWIDTH_PER_RATE
    edge = float(band) * new_dt
    if not 0 < edge < 0.5:
        raise TrialError(f"band {band!r} Hz must lie between 0 and the new Nyquist frequency "
                         f"{0.5 / new_dt:.4g} Hz")
    return edge


def _allowed_units_text() -> str:
    parts = []
    for q in QUANTITIES:
        us = [u for u, (qq, _) in UNITS.items() if qq == q]
        parts.append(f"{', '.join(us)} ({q})")
    return "; ".join(parts) + f"; g means standard gravity {STANDARD_GRAVITY} m/s^2"


def unit_factor(unit: str, quantity: str | None = None) -> float:
    """Return the factor that converts values in ``unit`` to SI.

    Parameters
    ----------
    unit : str
        One of the keys of :data:`UNITS` ('m', 'mm', 'm/s', 'mm/s', 'm/s^2', 'g').
    quantity : str, optional
        If given, the unit must measure this quantity.

    Returns
    -------
    float
        SI value = value in ``unit`` × factor (e.g. 1e-3 for 'mm', 9.80665 for 'g').

    Raises
    ------
    TrialError
        For an unknown unit, or a unit that does not measure ``quantity``.
    """
    if unit not in UNITS:
        raise TrialError(f"unknown unit {unit!r}; allowed units: {_allowed_units_text()}")
    q, factor = UNITS[unit]
    if quantity is not None and q != quantity:
        ok = [u for u, (qq, _) in UNITS.items() if qq == quantity]
        raise TrialError(
            f"unit {unit!r} measures {q}, but the quantity is {quantity!r}; "
            f"use one of {ok} for {quantity}"
        )
    return factor


# --------------------------------------------------------------------------------------
# Validation helpers shared by Trial and read_trial
# --------------------------------------------------------------------------------------
def _as_series(x: Any, what: str) -> np.ndarray:
    try:
        a = np.array(x, dtype=float)
    except (TypeError, ValueError):
        raise TrialError(f"{what} must be a 1-D array of numbers") from None
    if a.ndim != 1:
        raise TrialError(f"{what} must be 1-D, got shape {a.shape}")
    return a


def _check_finite(a: np.ndarray, what: str) -> None:
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        shown = ", ".join(str(i) for i in bad[:5]) + (", ..." if bad.size > 5 else "")
        raise TrialError(
            f"{what} has {bad.size} NaN/inf value(s) at sample index {shown} (0-based); "
            "remove or fill those samples (e.g. drop the rows) before using the trial"
        )


def _check_increasing(t: np.ndarray, what: str) -> None:
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise TrialError(
            f"{what} must be strictly increasing, but sample {i} (0-based, t = {t[i]!r} s) "
            f"does not come after sample {i - 1} (t = {t[i - 1]!r} s); {bad.size} such "
            "step(s) in all. Sort the samples by time and drop repeated time stamps "
            "(e.g. numpy.unique(times, return_index=True))"
        )


def _check_initial(initial: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(initial)
    unknown = sorted(set(out) - set(_INITIAL_KEYS))
    if unknown:
        allowed = ", ".join(f"{k} ({u})" if u else k for k, u in _INITIAL_KEYS.items())
        raise TrialError(f"unknown [initial] keys {unknown}; allowed: {allowed}")
    for key, unit in _INITIAL_KEYS.items():
        if key not in out:
            continue
        v = out[key]
        if unit is None:
            if not isinstance(v, str):
                raise TrialError(f"[initial] {key} must be a string, got {v!r}")
        elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise TrialError(f"[initial] {key} must be a finite number in {unit}, got {v!r}")
        else:
            out[key] = float(v)
    return out


def _check_analysis(analysis: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(analysis)
    unknown = sorted(set(out) - set(ANALYSIS_KEYS))
    if unknown:
        raise TrialError(f"unknown [analysis] keys {unknown}; allowed: {list(ANALYSIS_KEYS)}")
    for key, types in ANALYSIS_KEYS.items():
        v = out.get(key)
        if v is None:
            continue
        ok = isinstance(v, types) and (bool not in types) == (not isinstance(v, bool))
        if ok and isinstance(v, float):
            ok = math.isfinite(v)
        if not ok:
            kind = " or ".join(t.__name__ for t in types)
            raise TrialError(f"[analysis] {key} must be a {kind}, got {v!r} (see data/README.md)")
    return out


def _content_sha256(times: np.ndarray, values: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(times, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(values, dtype="<f8").tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------------------
# The record
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Trial:
    """One measured (or simulated) sensor time series, in SI units.

    Parameters
    ----------
    times : ndarray, shape (T,)
        Sample times in s, strictly increasing (need not be uniform), T >= 2.
    values : ndarray, shape (T,)
        The measured quantity in SI units (m, m/s or m/s^2), finite.
    quantity : str
        'displacement', 'velocity' or 'acceleration'. The beam's ``quantity`` is set
        to this value (the trial's signal is authoritative).
    beam : Beam
        The beam, with its ``sensor_position`` (m from the clamp).
    name : str
        A short label.
    source : dict
        Provenance: ``file`` (path of the data file read), ``sha256`` (of that file's
        bytes), ``unit`` (the unit the values were converted from), ``processing``
        (list of strings: what was done since, e.g. windows, decimation).
    t0 : float or None
        Time in s at which the model's initial condition applies; must be
        <= ``times[0]``. None means ``times[0]``.
    initial : dict
        What is known of the initial condition: ``tip_deflection`` (m),
        ``tip_impulse`` (N s), ``note`` (str).
    analysis : dict
        Choices of the analysis fixed by the trial (``[analysis]``, keys
        :data:`ANALYSIS_KEYS`); what is not given is chosen by
        :func:`bayesbeam.trials.preprocess.plan`.
    meta : dict
        Free-form metadata (TOML-serialisable values).
    bandwidth : float or None
        Sensor bandwidth in Hz as given (``[signal] bandwidth``; ``inf`` for a sensor
        without an anti-alias filter); None: the default :attr:`sensor_band`.

    Notes
    -----
    Arrays are copied and made read-only. Two trials compare equal only if they are
    the same object (arrays have no single truth value).
    """

    times: np.ndarray
    values: np.ndarray
    quantity: str
    beam: Beam
    name: str = "trial"
    source: dict[str, Any] = field(default_factory=dict)
    t0: float | None = None
    initial: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    bandwidth: float | None = None
    analysis: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _as_series(self.times, "times")
        y = _as_series(self.values, "values")
        if t.shape != y.shape:
            raise TrialError(
                f"times and values must have the same length, got {t.size} and {y.size}"
            )
        if t.size < 2:
            raise TrialError(f"a trial needs at least 2 samples, got {t.size}")
        _check_finite(t, "times")
        _check_finite(y, "values")
        _check_increasing(t, "times")
        if self.quantity not in QUANTITIES:
            raise TrialError(f"quantity must be one of {QUANTITIES}, got {self.quantity!r}")
        if not isinstance(self.beam, Beam):
            raise TrialError(
                f"beam must be a bayesbeam.physics.beam.Beam, got {type(self.beam).__name__}"
            )
        if not isinstance(self.name, str):
            raise TrialError(f"name must be a string, got {self.name!r}")
        t0 = float(t[0]) if self.t0 is None else self.t0
        if (
            isinstance(t0, (bool, np.bool_))
            or not isinstance(t0, (int, float, np.integer, np.floating))
            or not math.isfinite(t0)
        ):
            raise TrialError(f"t0 must be a finite time in s, got {self.t0!r}")
        if t0 > t[0]:
            raise TrialError(
                f"t0 = {t0!r} s lies after the first sample ({t[0]!r} s); the model's initial "
                "condition must apply at or before the first sample"
            )
        t.setflags(write=False)
        y.setflags(write=False)
        beam = self.beam
        if beam.quantity != self.quantity:
            beam = beam.replace(quantity=self.quantity)
        source = dict(self.source)
        source["processing"] = list(source.get("processing", []))
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "values", y)
        object.__setattr__(self, "beam", beam)
        object.__setattr__(self, "t0", float(t0))
        object.__setattr__(self, "source", source)
        object.__setattr__(self, "initial", _check_initial(self.initial))
        object.__setattr__(self, "analysis", _check_analysis(self.analysis))
        object.__setattr__(self, "meta", dict(self.meta))
        if self.bandwidth is not None:
            bw = self.bandwidth
            if (isinstance(bw, (bool, np.bool_)) or not isinstance(bw, (int, float, np.number))
                    or math.isnan(bw) or not bw > 0):
                raise TrialError(
                    f"bandwidth must be a positive number of Hz (inf: no anti-alias filter), "
                    f"got {bw!r}"
                )
            object.__setattr__(self, "bandwidth", float(bw))

    # -- properties -------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.times.size)

    @property
    def sensor_position(self) -> float:
        """Sensor position in m from the clamp (the tip when the beam gives none)."""
        return self.beam.sensor_x

    @property
    def duration(self) -> float:
        """``times[-1] - times[0]`` in s."""
        return float(self.times[-1] - self.times[0])

    @property
    def dt(self) -> float:
        """Mean sampling step ``(times[-1] - times[0]) / (T - 1)`` in s.

        For non-uniform stamps this is only the mean step; check :attr:`is_uniform`.
        """
        return self.duration / (self.times.size - 1)

    @property
    def sensor_band(self) -> float:
        """Sensor bandwidth in Hz: :attr:`bandwidth` if given, else the default.

        The default is :data:`BANDWIDTH_PER_RATE` times the sampling rate (the inverse
        of the median step); ``inf`` means no anti-alias filter.
        """
        if self.bandwidth is not None:
            return self.bandwidth
        return BANDWIDTH_PER_RATE / float(np.median(np.diff(self.times)))

    @property
    def is_uniform(self) -> bool:
        """True when every step is within :data:`UNIFORM_RTOL` of the mean step."""
        steps = np.diff(self.times)
        return bool(np.max(np.abs(steps - self.dt)) <= UNIFORM_RTOL * self.dt)

    @property
    def sha256(self) -> str:
        """SHA-256 (hex) of the source data file's bytes, as recorded in ``source``.

        For a trial that never came from a file (no ``source['sha256']``), the SHA-256
        of the float64 little-endian bytes of ``times`` followed by ``values``.
        """
        s = self.source.get("sha256")
        return str(s) if s else _content_sha256(self.times, self.values)

    # -- derived trials ---------------------------------------------------------------
    def _derived(self, times: np.ndarray, values: np.ndarray, step: str) -> Trial:
        source = dict(self.source)
        source["processing"] = [*self.source.get("processing", []), step]
        return dataclasses.replace(self, times=times, values=values, source=source)

    def window(self, t_start: float, t_end: float) -> Trial:
        """Return the samples with ``t_start <= t <= t_end`` (s), keeping :attr:`t0`.

        Parameters
        ----------
        t_start, t_end : float
            Window edges in s, on the trial's own time axis.

        Returns
        -------
        Trial
            The windowed trial; ``source['processing']`` records the window.

        Raises
        ------
        TrialError
            If ``t_start >= t_end`` or fewer than 2 samples fall in the window.
        """
        a, b = float(t_start), float(t_end)
        if not a < b:
            raise TrialError(f"window start ({a} s) must come before its end ({b} s)")
        keep = (self.times >= a) & (self.times <= b)
        if np.count_nonzero(keep) < 2:
            raise TrialError(
                f"window [{a}, {b}] s holds {np.count_nonzero(keep)} sample(s); the trial "
                f"spans [{self.times[0]}, {self.times[-1]}] s — choose edges inside it"
            )
        return self._derived(self.times[keep], self.values[keep], f"window [{a!r}, {b!r}] s")

    def decimate(self, factor: int, band: float | None = None) -> Trial:
        """Low-pass filter and keep every ``factor``-th sample (uniform sampling only).

        Uses the zero-phase Kaiser FIR of :func:`anti_alias_taps` (pass band to the
        new rate / 2.56, 100 dB from the new Nyquist frequency). Output samples whose
        filter support would reach past either end of the data (``half`` input samples,
        ``len(anti_alias_taps(q)) // 2``: 59 for q = 2, 235 for q = 8) are dropped;
        :attr:`t0` is kept, so the initial condition still applies at the same
        instant. Keep the signal's content below about 0.8 of the new Nyquist
        frequency (the filter's transition band).

        Parameters
        ----------
        factor : int
            Decimation factor q >= 1 (1 returns the trial unchanged).
        band : float, optional
            Pass band of the filter in Hz (below the new Nyquist frequency); default the
            new rate / 2.56. The result's :attr:`sensor_band` is at most this.

        Returns
        -------
        Trial
            Sampled at ``q * dt``; ``times`` are a subset of the original stamps.

        Raises
        ------
        TrialError
            For a non-integer or non-positive factor, non-uniform time stamps (use
            :meth:`resample`), or too few samples left.
        """
        if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
            raise TrialError(f"decimation factor must be an integer >= 1, got {factor!r}")
        q = int(factor)
        if q == 1:
            return self
        if not self.is_uniform:
            raise TrialError(
                "decimate needs uniformly sampled data (steps within "
                f"{UNIFORM_RTOL:g} of the mean step); these stamps are not uniform. Use "
                "Trial.resample(dt) for non-uniform stamps"
            )
        edge = _edge(band, q * self.dt)
        return self._decimated(self.times, self.values, q, f"decimate {q} (FIR, zero phase)",
                               edge)

    def _decimated(self, t: np.ndarray, y: np.ndarray, q: int, step: str,
                   edge: float = BANDWIDTH_PER_RATE) -> Trial:
        taps = anti_alias_taps(q, edge)
        half = taps.size // 2
        # Zero phase: tap `half` sits on the output sample (odd, symmetric filter).
        yd = scipy.signal.fftconvolve(y, taps)[half : half + y.size][::q]
        k = np.arange(yd.size)
        # Keep outputs whose filter support [k q - half, k q + half] lies inside the data.
        keep = (k * q - half >= 0) & (k * q + half <= t.size - 1)
        if np.count_nonzero(keep) < 2:
            raise TrialError(
                f"too few samples ({t.size}) to decimate by {q}: the filter needs "
                f"{2 * half + 1} samples plus 2 outputs; use a longer record or a smaller factor"
            )
        idx = k[keep]
        out = self._derived(t[idx * q], yd[idx], step)
        # The decimation filter limits the band to that of the new rate.
        band = min(self.sensor_band, edge / (q * float(np.median(np.diff(t)))))
        return dataclasses.replace(out, bandwidth=band)

    def resample(self, dt: float, max_gap: float | None = None,
                 band: float | None = None) -> Trial:
        """Resample onto a uniform grid of step ``dt`` (s) with an anti-alias filter.

        For non-uniform stamps (e.g. software-timed accelerometers): the signal is
        interpolated by a cubic spline (not-a-knot) onto a uniform grid of step
        ``h = dt / q`` with ``q = ceil(0.99 dt / median step)`` (so h is at most ~1 %
        coarser than the native sampling), then decimated by q as in :meth:`decimate`.
        The spline errs by at most ``(5/384) (2 pi f h_s)^4`` of a component at
        frequency f between stamps ``h_s`` apart (de Boor 2001, ch. V); linear
        interpolation's ``(2 pi f h_s)^2 / 8`` was 100 times larger on jittered
        stamps with modes at a quarter of the native rate, and its error is broadband,
        so the filter cannot remove it. The largest gap is recorded in
        ``source['processing']``; ``max_gap`` drops the outputs it touches.
        :attr:`t0` is kept.

        Parameters
        ----------
        dt : float
            New sampling step in s, at least the median native step.
        max_gap : float, optional
            Native steps longer than this (s) are gaps that interpolation cannot bridge:
            every output sample whose interpolation or anti-alias filter reaches into
            one is dropped (the output is then a uniform grid with holes, which the
            forward model simulates on the full grid). None keeps every sample.
        band : float, optional
            Pass band of the anti-alias filter in Hz, as for :meth:`decimate`.

        Returns
        -------
        Trial
            Sampled at ``dt`` (uniform unless ``max_gap`` dropped samples), starting at
            ``times[0] + k0 dt`` (the first filter-edge samples are dropped).

        Raises
        ------
        TrialError
            If ``dt`` is not a positive number or is finer than the native sampling.
        """
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not dt > 0:
            raise TrialError(f"resampling step dt must be a positive number in s, got {dt!r}")
        steps = np.diff(self.times)
        med = float(np.median(steps))
        if dt < med * (1 - 1e-9):
            raise TrialError(
                f"dt = {dt} s is finer than the native median step {med} s; resampling "
                "only reduces the rate (choose dt >= the median step)"
            )
        # q = ceil(dt / med), with 1 % slack so that dt = 10.005 median steps gives q = 10.
        q = max(1, math.ceil(dt / med * (1 - 1e-2)))
        h = dt / q
        n = int(np.floor(self.duration / h * (1 + 1e-12))) + 1
        grid = self.times[0] + h * np.arange(n)
        grid = grid[grid <= self.times[-1]]
        fine = scipy.interpolate.CubicSpline(self.times, self.values)(grid)
        step = (
            f"resample dt={dt!r} s (cubic-spline interpolation to {h!r} s, largest native gap "
            f"{float(steps.max())!r} s, then FIR decimation by {q})"
        )
        edge = _edge(band, dt)
        out = (self._derived(grid, fine, step) if q == 1
               else self._decimated(grid, fine, q, step, edge))
        if max_gap is None:
            return out
        if isinstance(max_gap, bool) or not isinstance(max_gap, (int, float)) or not max_gap > 0:
            raise TrialError(f"max_gap must be a positive number of s, got {max_gap!r}")
        gaps = np.flatnonzero(steps > max_gap)
        if gaps.size == 0:
            return out
        # Output k depends on the data within +- reach of it: the decimation FIR's half
        # length (see _decimated) plus the spline's, whose error from a gap decays by
        # 2 - sqrt(3) = 0.27 per knot (de Boor 2001, ch. V): 1e-6 after 10 stamps.
        reach = h * (0 if q == 1 else anti_alias_taps(q, edge).size // 2) + 10 * med
        a, b = self.times[gaps], self.times[gaps + 1]
        tau = out.times
        touched = np.searchsorted(a, tau + reach) - np.searchsorted(b, tau - reach, side="right")
        keep = touched <= 0
        if np.count_nonzero(keep) < 2:
            raise TrialError(
                f"every resampled sample lies within reach of a gap longer than max_gap = "
                f"{max_gap} s; raise max_gap or resample more coarsely"
            )
        return out._derived(
            out.times[keep], out.values[keep],
            f"dropped {int(keep.size - np.count_nonzero(keep))} resampled samples within "
            f"{reach!r} s of {gaps.size} native gaps longer than {max_gap!r} s",
        )
