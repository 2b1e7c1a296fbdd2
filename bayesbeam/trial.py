"""Measured or simulated trials: a sensor time series plus the beam it came from.

A trial is stored as a small TOML file that points at a CSV file (format documented
in ``data/README.md``)::

    name = "beam1-trial1"

    [signal]
    file = "beam1-trial1.csv"        # relative to this TOML file
    time_column = "time_s"
    value_column = "displacement_mm"
    quantity = "displacement"        # displacement | velocity | acceleration
    unit = "mm"                      # m, mm, m/s, mm/s, m/s^2, g (g = 9.80665 m/s^2)
    sensor_position = 0.3048         # m from the clamp

    [beam]                           # read with Beam.from_dict (SI units)
    length = 0.3048
    width = 0.127
    thickness = 0.00072
    mass = 0.021

    [initial]                        # optional
    tip_deflection = 0.005           # m
    note = "released from a static tip load"

    [meta]                           # optional, free-form

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
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.signal

from bayesbeam.beam import QUANTITIES, Beam, BeamError

__all__ = [
    "STANDARD_GRAVITY",
    "UNIFORM_RTOL",
    "UNITS",
    "Trial",
    "TrialError",
    "read_trial",
    "unit_factor",
    "write_trial",
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

_SIGNAL_REQUIRED = (
    "file",
    "time_column",
    "value_column",
    "quantity",
    "unit",
    "sensor_position",
)
_SIGNAL_OPTIONAL = ("t0", "delimiter")
_TOP_KEYS = ("name", "format_version", "signal", "beam", "initial", "meta")
_INITIAL_KEYS = {"tip_deflection": "m", "tip_impulse": "N s", "note": None}
FORMAT_VERSION = 1


class TrialError(ValueError):
    """A trial (file or record) is invalid; the message says what and how to fix it."""


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
    meta : dict
        Free-form metadata (TOML-serialisable values).

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
            raise TrialError(f"beam must be a bayesbeam.beam.Beam, got {type(self.beam).__name__}")
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
        object.__setattr__(self, "meta", dict(self.meta))

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

    def decimate(self, factor: int) -> Trial:
        """Low-pass filter and keep every ``factor``-th sample (uniform sampling only).

        Uses :func:`scipy.signal.decimate` with its zero-phase FIR filter (Hamming
        window, 20·factor + 1 taps, cutoff at the new Nyquist frequency). Output
        samples whose filter support would reach past either end of the data (the
        first and last ~10) are dropped, because the filter pads with zeros there;
        :attr:`t0` is kept, so the initial condition still applies at the same
        instant. Keep the signal's content below about 0.8 of the new Nyquist
        frequency (the filter's transition band).

        Parameters
        ----------
        factor : int
            Decimation factor q >= 1 (1 returns the trial unchanged).

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
        return self._decimated(self.times, self.values, q, f"decimate {q} (FIR, zero phase)")

    def _decimated(self, t: np.ndarray, y: np.ndarray, q: int, step: str) -> Trial:
        half = 10 * q  # scipy.signal.decimate's FIR half length for ftype='fir'
        yd = scipy.signal.decimate(y, q, ftype="fir", zero_phase=True)
        k = np.arange(yd.size)
        # Keep outputs whose filter support [k q - half, k q + half] lies inside the data.
        keep = (k * q - half >= 0) & (k * q + half <= t.size - 1)
        if np.count_nonzero(keep) < 2:
            raise TrialError(
                f"too few samples ({t.size}) to decimate by {q}: the filter needs "
                f"{2 * half + 1} samples plus 2 outputs; use a longer record or a smaller factor"
            )
        idx = k[keep]
        return self._derived(t[idx * q], yd[idx], step)

    def resample(self, dt: float) -> Trial:
        """Resample onto a uniform grid of step ``dt`` (s) with an anti-alias filter.

        For non-uniform stamps (e.g. software-timed accelerometers): the signal is
        linearly interpolated onto a uniform grid of step ``h = dt / q`` with
        ``q = ceil(0.99 dt / median step)`` (so h is at most ~1 % coarser than the
        native sampling),
        then decimated by q as in :meth:`decimate`. Linear interpolation of a
        component at frequency f has a relative amplitude error of at most
        ``(2 pi f h_gap)^2 / 8`` across a gap ``h_gap``; the largest gap is recorded
        in ``source['processing']``. :attr:`t0` is kept.

        Parameters
        ----------
        dt : float
            New sampling step in s, at least the median native step.

        Returns
        -------
        Trial
            Uniformly sampled at ``dt``, starting at ``times[0] + k0 dt`` (the first
            filter-edge samples are dropped).

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
        fine = np.interp(grid, self.times, self.values)
        step = (
            f"resample dt={dt!r} s (linear interpolation to {h!r} s, largest native gap "
            f"{float(steps.max())!r} s, then FIR decimation by {q})"
        )
        if q == 1:
            return self._derived(grid, fine, step)
        return self._decimated(grid, fine, q, step)


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------
def _file_sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _read_csv(
    csv_path: Path, time_column: str, value_column: str, delimiter: str
) -> tuple[np.ndarray, np.ndarray, str]:
    try:
        raw = csv_path.read_bytes()
    except FileNotFoundError:
        raise TrialError(f"signal file {csv_path} not found") from None
    text = raw.decode("utf-8-sig")
    lines = text.splitlines()
    header_at = next(
        (i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")),
        None,
    )
    if header_at is None:
        raise TrialError(f"{csv_path} is empty; it needs a header line with column names")
    names = [c.strip().strip('"').strip("'") for c in lines[header_at].split(delimiter)]
    cols = []
    for role, col in (("time_column", time_column), ("value_column", value_column)):
        if col not in names:
            raise TrialError(
                f"{role} {col!r} is not a column of {csv_path}; available columns: {names}"
            )
        cols.append(names.index(col))
    body = lines[header_at + 1 :]
    if not any(ln.strip() and not ln.lstrip().startswith("#") for ln in body):
        raise TrialError(f"{csv_path} has a header but no data rows")
    try:
        data = np.loadtxt(body, delimiter=delimiter, usecols=cols, ndmin=2, comments="#")
    except ValueError as err:
        raise TrialError(
            f"could not read numbers from {csv_path}: {err}. Every data row needs a number "
            f"in columns {time_column!r} and {value_column!r} (delimiter {delimiter!r})"
        ) from None
    return data[:, 0], data[:, 1], _file_sha256(raw)


def _need_str(table: Mapping[str, Any], key: str, where: str) -> str:
    v = table[key]
    if not isinstance(v, str) or not v:
        raise TrialError(f"{where} {key} must be a non-empty string, got {v!r}")
    return v


def read_trial(path: str | Path) -> Trial:
    """Read a trial from its TOML file and the CSV file it names.

    Parameters
    ----------
    path : str or Path
        The trial's TOML file (format in ``data/README.md`` and this module's
        docstring).

    Returns
    -------
    Trial
        Values converted to SI units; ``source`` holds the CSV path, its SHA-256 and
        the unit converted from.

    Raises
    ------
    TrialError
        For a missing or invalid file, missing or unknown keys, a missing column, an
        unknown unit, NaN/inf data, non-increasing times, a sensor beyond the free
        end, or an invalid beam; the message says how to fix it.
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise TrialError(f"trial file {path} not found") from None
    except tomllib.TOMLDecodeError as err:
        raise TrialError(f"{path} is not valid TOML: {err}") from None
    unknown = sorted(set(doc) - set(_TOP_KEYS))
    if unknown:
        raise TrialError(f"{path}: unknown top-level keys {unknown}; allowed: {list(_TOP_KEYS)}")
    signal = doc.get("signal")
    if not isinstance(signal, dict):
        raise TrialError(
            f"{path} needs a [signal] table with keys {list(_SIGNAL_REQUIRED)} (see data/README.md)"
        )
    missing = [k for k in _SIGNAL_REQUIRED if k not in signal]
    if missing:
        raise TrialError(
            f"{path}: [signal] is missing {missing} (required: {list(_SIGNAL_REQUIRED)})"
        )
    extra = sorted(set(signal) - set(_SIGNAL_REQUIRED) - set(_SIGNAL_OPTIONAL))
    if extra:
        raise TrialError(
            f"{path}: unknown [signal] keys {extra}; allowed: "
            f"{list(_SIGNAL_REQUIRED + _SIGNAL_OPTIONAL)}"
        )
    where = f"{path}: [signal]"
    file = _need_str(signal, "file", where)
    time_column = _need_str(signal, "time_column", where)
    value_column = _need_str(signal, "value_column", where)
    quantity = _need_str(signal, "quantity", where)
    if quantity not in QUANTITIES:
        raise TrialError(f"{where} quantity must be one of {QUANTITIES}, got {quantity!r}")
    unit = _need_str(signal, "unit", where)
    try:
        factor = unit_factor(unit, quantity)
    except TrialError as err:
        raise TrialError(f"{where} {err}") from None
    delimiter = signal.get("delimiter", ",")
    if not isinstance(delimiter, str) or len(delimiter) != 1:
        raise TrialError(f"{where} delimiter must be a single character, got {delimiter!r}")
    xs = signal["sensor_position"]
    if (
        isinstance(xs, bool)
        or not isinstance(xs, (int, float))
        or not (math.isfinite(xs) and xs > 0)
    ):
        raise TrialError(f"{where} sensor_position must be a positive number in m, got {xs!r}")

    beam_d = doc.get("beam")
    if not isinstance(beam_d, dict):
        raise TrialError(
            f"{path} needs a [beam] table (length, width, thickness, mass, ...; SI units)"
        )
    for key in ("sensor_position", "quantity"):
        if key in beam_d:
            raise TrialError(f"{path}: give {key} in [signal] only, not in [beam]")
    length = beam_d.get("length")
    if isinstance(length, (int, float)) and not isinstance(length, bool) and xs > length:
        raise TrialError(
            f"{where} sensor_position {xs} m lies beyond the free end of the beam (length "
            f"{length} m); give the distance from the clamp in metres"
        )
    try:
        beam = Beam.from_dict({**beam_d, "sensor_position": float(xs), "quantity": quantity})
    except BeamError as err:
        raise TrialError(f"{path}: [beam]: {err}") from None

    initial = doc.get("initial", {})
    meta = doc.get("meta", {})
    for key, tab in (("initial", initial), ("meta", meta)):
        if not isinstance(tab, dict):
            raise TrialError(f"{path}: {key} must be a table ([{key}]), got {tab!r}")
    name = doc.get("name", path.stem)
    if not isinstance(name, str):
        raise TrialError(f"{path}: name must be a string, got {name!r}")
    t0 = signal.get("t0")

    csv_path = path.parent / file
    if not csv_path.is_file():
        raise TrialError(
            f"signal file {csv_path} not found ([signal] file = {file!r} in {path} is "
            "resolved relative to the TOML file's folder)"
        )
    times, raw, digest = _read_csv(csv_path, time_column, value_column, delimiter)
    source = {
        "file": str(csv_path.resolve()),
        "sha256": digest,
        "unit": unit,
        "trial_file": str(path.resolve()),
        "processing": [],
    }
    try:
        return Trial(
            times=times,
            values=raw * factor,
            quantity=quantity,
            beam=beam,
            name=name,
            source=source,
            t0=t0,
            initial=initial,
            meta=meta,
        )
    except TrialError as err:
        raise TrialError(f"{csv_path} (columns {time_column!r}, {value_column!r}): {err}") from None


# --------------------------------------------------------------------------------------
# Writing (tomllib reads TOML but has no writer; this is a small one for our tables)
# --------------------------------------------------------------------------------------
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_ESCAPES = {
    '"': '\\"',
    "\\": "\\\\",
    "\b": "\\b",
    "\t": "\\t",
    "\n": "\\n",
    "\f": "\\f",
    "\r": "\\r",
}


def _toml_str(s: str) -> str:
    out = []
    for ch in s:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(k: Any) -> str:
    if not isinstance(k, str):
        raise TrialError(f"TOML keys must be strings, got {k!r}")
    return k if _BARE_KEY.fullmatch(k) else _toml_str(k)


def _is_table(v: Any) -> bool:
    return isinstance(v, Mapping)


def _is_table_array(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(v) > 0 and all(isinstance(x, Mapping) for x in v)


def _toml_value(v: Any) -> str:
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # shortest round-trip repr; 'inf', 'nan', '1e-05' are valid TOML
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, Path):
        return _toml_str(str(v))
    if isinstance(v, (list, tuple, np.ndarray)):
        items = list(v)
        if any(isinstance(x, Mapping) for x in items):
            raise TrialError("a TOML array may not mix tables and values")
        return "[" + ", ".join(_toml_value(x) for x in items) + "]"
    raise TrialError(f"cannot write {type(v).__name__} value {v!r} to TOML")


def _emit(lines: list[str], prefix: tuple[str, ...], table: Mapping[str, Any]) -> None:
    for k, v in table.items():
        if not _is_table(v) and not _is_table_array(v):
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        name = ".".join(_toml_key(p) for p in (*prefix, k))
        if _is_table(v):
            lines += ["", f"[{name}]"]
            _emit(lines, (*prefix, k), v)
        elif _is_table_array(v):
            for item in v:
                lines += ["", f"[[{name}]]"]
                _emit(lines, (*prefix, k), item)


def _toml_dumps(doc: Mapping[str, Any]) -> str:
    """Serialise nested mappings of str/int/float/bool/lists to TOML text."""
    lines: list[str] = []
    _emit(lines, (), doc)
    return "\n".join(lines).lstrip("\n") + "\n"


def _column_name(quantity: str, unit: str) -> str:
    return f"{quantity}_{unit}"


def write_trial(trial: Trial, path: str | Path, *, unit: str | None = None) -> Path:
    """Write a trial as a TOML file plus a CSV file beside it.

    The CSV gets the TOML's name with suffix ``.csv`` and columns ``time_s`` and
    ``<quantity>_<unit>``; numbers are written with 17 significant digits, so SI
    values read back bit for bit (other units to within a rounding of the
    conversion factor). If the trial came from a file, ``[meta] derived_from``
    records that file, its SHA-256 and the processing done since.

    Parameters
    ----------
    trial : Trial
        The trial to write.
    path : str or Path
        The TOML file to write (suffix ``.toml``); its folder is created if needed.
    unit : str, optional
        Unit of the written values (default: the SI unit of the quantity).

    Returns
    -------
    Path
        The TOML file written.

    Raises
    ------
    TrialError
        For a bad suffix, a unit that does not fit the quantity, or metadata that
        cannot be written to TOML.
    """
    path = Path(path)
    if path.suffix != ".toml":
        raise TrialError(f"trial file name must end in .toml, got {path.name!r}")
    unit = _SI_UNIT[trial.quantity] if unit is None else unit
    factor = unit_factor(unit, trial.quantity)
    csv_path = path.with_suffix(".csv")
    value_column = _column_name(trial.quantity, unit)

    beam = trial.beam.to_dict()
    beam.pop("sensor_position", None)
    beam.pop("quantity", None)
    meta = dict(trial.meta)
    if trial.source.get("file"):
        meta["derived_from"] = {
            "file": str(trial.source["file"]),
            "sha256": str(trial.source.get("sha256", "")),
            "unit": str(trial.source.get("unit", "")),
            "processing": [str(s) for s in trial.source.get("processing", [])],
        }
    doc: dict[str, Any] = {
        "name": trial.name,
        "format_version": FORMAT_VERSION,
        "signal": {
            "file": csv_path.name,
            "time_column": "time_s",
            "value_column": value_column,
            "quantity": trial.quantity,
            "unit": unit,
            "sensor_position": trial.sensor_position,
            "t0": trial.t0,
        },
        "beam": beam,
    }
    if trial.initial:
        doc["initial"] = dict(trial.initial)
    if meta:
        doc["meta"] = meta
    text = (
        "# bayesbeam trial (format: data/README.md). Values in the CSV are in "
        f"{unit}; beam in SI units (mass {trial.beam.beam_mass!r} kg).\n" + _toml_dumps(doc)
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    values = trial.values if factor == 1.0 else trial.values / factor
    data = np.column_stack([trial.times, values])
    with csv_path.open("w", encoding="utf-8", newline="\n") as fh:
        fh.write(f"time_s,{value_column}\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.17g")
    path.write_text(text, encoding="utf-8")
    return path
