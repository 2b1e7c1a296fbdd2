"""Trial files: read and write a trial as a TOML file plus the CSV file it names.

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
    bandwidth = 100.0                # Hz, optional: the sensor's anti-alias band
                                     # (default sampling rate / 2.56; inf: unfiltered)

    [beam]                           # read with Beam.from_dict (SI units)
    length = 0.3048
    width = 0.127
    thickness = 0.00072
    mass = 0.021

    [initial]                        # optional
    tip_deflection = 0.005           # m
    note = "released from a static tip load"

    [analysis]                       # optional: fix choices of bayesbeam.trials.preprocess
    start = 0.25                     # s (also end, rate, initial, offset, max_samples, auto)

    [meta]                           # optional, free-form

Values are converted to SI units when read, so a :class:`~bayesbeam.trials.trial.Trial`
always holds SI values. The in-memory record lives in :mod:`bayesbeam.trials.trial`, which
also re-exports :func:`read_trial` and :func:`write_trial` (their historical home).
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import read_toml
from bayesbeam.physics.beam import QUANTITIES, Beam, BeamError
from bayesbeam.trials.realdata import RealDataError, record_at
from bayesbeam.trials.trial import _SI_UNIT, Trial, TrialError, unit_factor

__all__ = ["FORMAT_VERSION", "read_trial", "write_trial"]

_SIGNAL_REQUIRED = (
    "file",
    "time_column",
    "value_column",
    "quantity",
    "unit",
    "sensor_position",
)
_SIGNAL_OPTIONAL = ("t0", "delimiter", "bandwidth")
#: Suffixes of data files that are not trial files (a clear error instead of a TOML
#: syntax error at their first line).
_DATA_SUFFIXES = (".csv", ".txt", ".dat", ".npy", ".npz", ".lvm", ".xlsx", ".xls", ".mat",
                  ".h5", ".hdf5", ".tdms", ".wav", ".uff", ".unv")
_TOP_KEYS = ("name", "format_version", "signal", "beam", "initial", "analysis", "meta")
FORMAT_VERSION = 1


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------
#: Longest column name a header may hold to count as a CSV header (and be echoed).
_MAX_NAME = 40


def _looks_like_csv(names: list[str], body: list[str], delimiter: str) -> bool:
    """Return True when a header reads as short column names over rows as wide.

    A file that is not the trial's CSV (a path slip onto another file) must not have its
    content echoed in an error message: only short, printable names of a header with at
    least two columns, whose first data row has as many fields, are shown.
    """
    if len(names) < 2 or any(not n or len(n) > _MAX_NAME or not n.isprintable()
                             for n in names):
        return False
    row = next((ln for ln in body if ln.strip() and not ln.lstrip().startswith("#")), None)
    return row is None or len(row.split(delimiter)) == len(names)


def _missing_column(csv_path: Path, role: str, col: str, names: list[str], body: list[str],
                    delimiter: str) -> str:
    """Return the message for a missing column (names echoed only from a CSV header)."""
    if _looks_like_csv(names, body, delimiter):
        return f"{role} {col!r} is not a column of {csv_path}; available columns: {names}"
    return (f"no column {col!r} ({role}) in {csv_path}: it does not look like the CSV the "
            f"trial describes (a header line of column names separated by {delimiter!r}, "
            "then rows of numbers); check [signal] file and delimiter")


def _read_csv(
    csv_path: Path, time_column: str, value_column: str, delimiter: str
) -> tuple[np.ndarray, np.ndarray, str]:
    try:
        raw = csv_path.read_bytes()
    except FileNotFoundError:
        raise TrialError(f"signal file {csv_path} not found") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise TrialError(
            f"signal file {csv_path} is not UTF-8 text (byte 0x{raw[err.start]:02x} at "
            f"position {err.start}); save it as UTF-8 (plain ASCII column names are safest)"
        ) from None
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
            raise TrialError(_missing_column(csv_path, role, col, names, lines[header_at + 1:],
                                             delimiter))
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
    # The digest of the bytes parsed here (not _util.file_sha256, whose second read of
    # the file could see other bytes).
    return data[:, 0], data[:, 1], hashlib.sha256(raw).hexdigest()


def _need_str(table: Mapping[str, Any], key: str, where: str) -> str:
    v = table[key]
    if not isinstance(v, str) or not v:
        raise TrialError(f"{where} {key} must be a non-empty string, got {v!r}")
    return v


def read_trial(path: str | Path) -> Trial:
    """Read a trial from its TOML file and the CSV file it names.

    A record file of one of the public measured data sets, where it lies in its data
    set (:func:`bayesbeam.trials.realdata.record_at`), is read as that record's raw
    trial (``load_enes`` / ``load_hrshm`` with ``raw=True``: the whole record, g
    converted to m/s², the beam from the data set's PROVENANCE.md), for
    :mod:`bayesbeam.trials.preprocess` to choose the analysis.

    Parameters
    ----------
    path : str or Path
        The trial's TOML file (format in ``data/README.md`` and this module's
        docstring), or a public data set's record file.

    Returns
    -------
    Trial
        Values converted to SI units; ``source`` holds the data file's path, its
        SHA-256 and the unit converted from.

    Raises
    ------
    TrialError
        For a missing or invalid file, a data file given where its trial file is
        meant, missing or unknown keys, a missing column, an unknown unit, NaN/inf
        data, non-increasing times, a sensor beyond the free end, or an invalid beam;
        the message says how to fix it.
    """
    path = Path(path)
    found = record_at(path)
    if found is not None:  # a public data set's own file, where it lies
        record, root = found
        try:
            return record.load(root=root, raw=True)
        except RealDataError as err:
            raise TrialError(str(err)) from None
    if path.suffix.lower() in _DATA_SUFFIXES:
        raise TrialError(
            f"{path} is a data file, not a trial file: bayesbeam reads a trial file (TOML) "
            "that names the data file and gives the beam, the sensor position, the "
            "quantity and the unit (data/README.md; `bayesbeam simulate` writes one). "
            "The public data sets' record files are read where they lie: "
            "enes-alu-release/<L>cm_adxl/<record>/accelerometer_data.npy and "
            "hrshm-steel-impulse/timeseries_data.lvm")
    try:
        doc = read_toml(path, what="trial file", error=TrialError)
    except UnicodeDecodeError as err:  # tomllib decodes the bytes itself
        raise TrialError(
            f"trial file {path} is not UTF-8 text (byte 0x{err.object[err.start]:02x} at "
            f"position {err.start}); save it as UTF-8"
        ) from None
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
    # Only a valid length can place the sensor beyond it; Beam names a zero or negative one.
    if (isinstance(length, (int, float)) and not isinstance(length, bool) and length > 0
            and xs > length):
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
    analysis = doc.get("analysis", {})
    for key, tab in (("initial", initial), ("analysis", analysis), ("meta", meta)):
        if not isinstance(tab, dict):
            raise TrialError(f"{path}: {key} must be a table ([{key}]), got {tab!r}")
    name = doc.get("name", path.stem)
    if not isinstance(name, str):
        raise TrialError(f"{path}: name must be a string, got {name!r}")
    t0 = signal.get("t0")
    bandwidth = signal.get("bandwidth")

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
        "time_column": time_column,
        "value_column": value_column,
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
            bandwidth=bandwidth,
            analysis=analysis,
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
    if trial.bandwidth is not None:
        doc["signal"]["bandwidth"] = trial.bandwidth
    if trial.initial:
        doc["initial"] = dict(trial.initial)
    if trial.analysis:
        doc["analysis"] = dict(trial.analysis)
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
