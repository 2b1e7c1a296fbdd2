"""Loaders that turn the public real data sets into :class:`~bayesbeam.trials.trial.Trial` s.

The data are not part of the repository (their licences and size): they are
expected in ``../shared/data/real`` beside the repository root, each set with a
``PROVENANCE.md`` that documents its source, licence, format and beam. Two sets:

``enes-alu-release`` (MIT, Copyright 2024 Enes Demirkaya)
    Aluminium cantilever (50.8 × 2 mm, free lengths 30/40/50/60 cm) released by
    hand from a tip deflection of 2 or 4 cm; ADXL357 acceleration (in g) 6 cm from
    the free end, software time stamps at ~3.9 kHz (NOT uniform), 20 s records.
``hrshm-steel-impulse`` (CC BY-SA 4.0, Chowdhury, Downey, Bakos and Conrad 2021)
    Steel cantilever (759 × 50.66 × 5.14 mm) struck by an impulse; IEPE
    accelerometer (in g) "close to the edge", uniform 1651.6 Hz, 49.6 s.

What the loaders do (each step is recorded in ``trial.source['processing']``):

1. read the file, record its SHA-256 and compare it with the checksum documented
   in PROVENANCE.md (``meta['sha256_matches_provenance']``);
2. subtract a baseline (enes: mean of the last 2 s of the record, where the motion
   has decayed; hrshm: mean of the quiet pre-impact segment);
3. convert g to m/s^2 (g = 9.80665 m/s^2);
4. find the release/impact as the largest |a| (enes: within the first ``search``
   s) and start the window at the first sample more than ``settle`` s after it,
   so the transient of the hand release (or the hammer contact and the highest
   modes it excites) is left out; the window lasts ``duration`` s.

The model's initial condition applies at the first sample of the window
(``trial.t0 = times[0]``); the state there is not a static deflection shape
(several modes are moving), so fits need a general initial state or must
estimate the modal amplitudes. Times are kept as recorded (not shifted to 0).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import file_sha256
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.trial import STANDARD_GRAVITY, Trial

__all__ = [
    "DEFAULT_ROOT",
    "ENES",
    "HRSHM",
    "RealDataError",
    "RealRecord",
    "enes_beam",
    "hrshm_beam",
    "list_real_datasets",
    "load_enes",
    "load_hrshm",
    "record_at",
    "resolve_root",
]

#: Default location of the real data sets, relative to the repository root (or cwd).
DEFAULT_ROOT = "../shared/data/real"
ENES = "enes-alu-release"
HRSHM = "hrshm-steel-impulse"

_REPO = Path(__file__).resolve().parents[2]

# Documented in enes-alu-release/PROVENANCE.md ("Checksums", sha256 first 16 hex digits).
_ENES_SHA256_PREFIX = {
    "08-12_21-08-55_2cmIDadxlAt6cm": "14afcbc67b956663",
    "08-12_21-13-02_2cmIDadxlAt6cm4000Hz": "901da35bbb786406",
    "08-12_11-41-04_adxl6cmfromtip2cmID": "f54e7e1b9a8ad4b9",
    "08-12_11-41-40_adxl6cmfromtip2cmID": "236008e97a7c6d98",
    "08-12_11-46-55_adxl6cmfromtip2cmID": "c7a09f96b25db2d0",
    "08-12_11-49-09_adxl6cmfromtip2cmID": "825f4cc38c24303d",
    "08-12_21-19-44_2cmIDadxlAt6cm": "0c3caec157470900",
    "08-12_21-20-44_2cmIDadxlAt6cm": "dfe84e925d7bba48",
    "08-12_21-23-29_4cmIDrun1": "15fcd6ef59468237",
    "08-12_21-23-58_4cmIDrun1": "dab85182b46b978a",
}
# points_data.xlsx of the source (measured peaks entered by hand), modes 1 and 2, Hz.
_ENES_DOCUMENTED_HZ = {30: (16.49, 107.6), 40: (9.383, 61.54), 50: (6.02, 39.63), 60: (4.25, 27.35)}
_HRSHM_SHA256 = "06912a5bdee18349fee5aeb3e373ac8b70e5cc98ff8df2c37b9b85ea5a305088"


class RealDataError(ValueError):
    """A real data set is missing or not as documented; the message says what to do."""


def resolve_root(root: str | Path = DEFAULT_ROOT) -> Path:
    """Find the real-data folder.

    Parameters
    ----------
    root : str or Path
        Absolute, or relative to the current directory or to the repository root
        (the folder holding ``bayesbeam/``), tried in that order.

    Returns
    -------
    Path
        The resolved folder.

    Raises
    ------
    RealDataError
        If no candidate folder exists.
    """
    root = Path(root)
    candidates = [root] if root.is_absolute() else [Path.cwd() / root, _REPO / root]
    for c in candidates:
        if c.is_dir():
            return c.resolve()
    tried = ", ".join(str(c) for c in candidates)
    raise RealDataError(
        f"real data folder {str(root)!r} not found (tried {tried}). The data sets are not "
        "shipped in the repository; place them at ../shared/data/real beside the repository "
        "root or pass root= to the loader"
    )


# --------------------------------------------------------------------------------------
# Listing
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RealRecord:
    """One loadable real record.

    Parameters
    ----------
    dataset : str
        'enes-alu-release' or 'hrshm-steel-impulse'.
    name : str
        Record label (folder name of the enes records).
    path : Path
        The data file.
    kwargs : dict
        Arguments of the loader that selects this record.
    """

    dataset: str
    name: str
    path: Path
    kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        """Short label: ``alu50-0`` (aluminium, free length in cm, repeat), ``steel``."""
        if self.dataset == ENES:
            return f"alu{self.kwargs['length_cm']}-{self.kwargs['index']}"
        return "steel"

    def load(self, root: str | Path = DEFAULT_ROOT, **options: Any) -> Trial:
        """Load the record with its loader (``options`` e.g. ``duration``).

        Parameters
        ----------
        root : str or Path
            The real-data folder (see :func:`resolve_root`).
        **options
            Further loader arguments.

        Returns
        -------
        Trial
        """
        loader = load_enes if self.dataset == ENES else load_hrshm
        return loader(**self.kwargs, root=root, **options)


def _enes_records(root: Path) -> dict[int, list[Path]]:
    out: dict[int, list[Path]] = {}
    base = root / ENES
    for d in sorted(base.glob("*cm_adxl")):
        m = re.fullmatch(r"(\d+)cm_adxl", d.name)
        if m is None:
            continue
        files = sorted(d.glob("*/accelerometer_data.npy"))
        if files:
            out[int(m.group(1))] = files
    return out


def list_real_datasets(root: str | Path = DEFAULT_ROOT) -> tuple[RealRecord, ...]:
    """Enumerate the real records present under ``root``.

    Parameters
    ----------
    root : str or Path
        The real-data folder (see :func:`resolve_root`).

    Returns
    -------
    tuple of RealRecord
        enes records sorted by length and folder name (``kwargs`` = length_cm,
        index), then the hrshm record if present.
    """
    base = resolve_root(root)
    recs = []
    for length_cm, files in _enes_records(base).items():
        for i, f in enumerate(files):
            recs.append(RealRecord(ENES, f.parent.name, f, {"length_cm": length_cm, "index": i}))
    lvm = base / HRSHM / "timeseries_data.lvm"
    if lvm.is_file():
        recs.append(RealRecord(HRSHM, lvm.stem, lvm, {}))
    return tuple(recs)


def record_at(path: str | Path) -> tuple[RealRecord, Path] | None:
    """Recognise a public data set's record file where it lies.

    The file is recognised by its place in the data set's documented layout (its own
    name and the folders above it), not by its content: the beam, the sensor and the
    units come from the data set's PROVENANCE.md, so a file of the same format from
    another beam must not be read as one of these (write a trial file for it instead).

    Parameters
    ----------
    path : str or Path
        ``ROOT/enes-alu-release/<L>cm_adxl/<folder>/accelerometer_data.npy`` (or that
        folder), or ``ROOT/hrshm-steel-impulse/timeseries_data.lvm``.

    Returns
    -------
    (RealRecord, Path) or None
        The record and the real-data folder ``ROOT`` to load it from; None for any
        other path.
    """
    p = Path(path)
    if p.is_dir() and (p / "accelerometer_data.npy").is_file():
        p = p / "accelerometer_data.npy"
    if not p.is_file():
        return None
    p = p.resolve()
    if p.name == "timeseries_data.lvm" and p.parent.name == HRSHM:
        return RealRecord(HRSHM, p.stem, p, {}), p.parent.parent
    m = re.fullmatch(r"(\d+)cm_adxl", p.parent.parent.name)
    if p.name == "accelerometer_data.npy" and m and p.parents[2].name == ENES:
        root = p.parents[3]
        length_cm = int(m.group(1))
        files = [f.resolve() for f in _enes_records(root).get(length_cm, [])]
        if p in files:
            return (RealRecord(ENES, p.parent.name, p,
                               {"length_cm": length_cm, "index": files.index(p)}), root)
    return None


# --------------------------------------------------------------------------------------
# Beams from PROVENANCE.md
# --------------------------------------------------------------------------------------
def enes_beam(length_cm: float) -> Beam:
    """Beam of the enes-alu-release set at a free length (PROVENANCE.md values).

    Width 50.8 mm, thickness 2 mm, aluminium density 2700 kg/m^3 (mass from these),
    nominal E = 70 GPa, sensor 6 cm from the free end, acceleration. The source's
    tip mass (10 g in its MATLAB script, 5 g in its README; sensor and wiring) is
    uncertain and NOT included (tip_mass = 0): estimate it, or set it with
    ``beam.replace(tip_mass=...)``.

    Parameters
    ----------
    length_cm : float
        Free length in cm (30, 40, 50 or 60 for the recorded data).

    Returns
    -------
    Beam
    """
    L = float(length_cm) / 100.0
    width, thickness, density = 50.8e-3, 2e-3, 2700.0
    return Beam.rectangular(
        L,
        width,
        thickness,
        density * L * width * thickness,
        E=70e9,
        sensor_position=L - 0.06,
        quantity="acceleration",
    )


def hrshm_beam() -> Beam:
    """Beam of the hrshm-steel-impulse set (PROVENANCE.md values, partly assumed).

    759 × 50.66 × 5.14 mm steel, density 7850 kg/m^3 and E = 200 GPa nominal (the
    grade is not documented). The free length is not documented: the overall length
    0.759 m is used (f1 then comes out ~9 % above the measured 6.62 Hz with these
    nominal values). The sensor is "close to the edge": taken at the tip. Shaker /
    load-cell attachment mass is unknown (tip_mass = 0).

    Returns
    -------
    Beam
    """
    L, width, thickness, density = 0.759, 50.66e-3, 5.14e-3, 7850.0
    return Beam.rectangular(
        L,
        width,
        thickness,
        density * L * width * thickness,
        E=200e9,
        sensor_position=L,
        quantity="acceleration",
    )


# --------------------------------------------------------------------------------------
# Loaders
# --------------------------------------------------------------------------------------
def _window_after(
    t: np.ndarray, t_peak: float, settle: float, duration: float | None, label: str
) -> np.ndarray:
    """Boolean mask of the analysis window: first sample > t_peak + settle, for duration."""
    start = int(np.searchsorted(t, t_peak + settle, side="right"))
    if start >= t.size - 1:
        raise RealDataError(f"{label}: no data after the peak at {t_peak:.3f} s + {settle} s")
    t_start = t[start]
    if duration is None:
        t_end = t[-1]
    else:
        if not (isinstance(duration, (int, float)) and duration > 0):
            raise RealDataError(
                f"duration must be a positive number of s or None, got {duration!r}"
            )
        t_end = t_start + float(duration)
        if t_end > t[-1] + 1e-9:
            raise RealDataError(
                f"{label}: duration {duration} s runs past the end of the record; at most "
                f"{t[-1] - t_start:.3f} s are available after the window start {t_start:.4f} s "
                "(or pass duration=None)"
            )
    mask = (t >= t_start) & (t <= t_end)
    return mask


def _check_settle(settle: float) -> float:
    if isinstance(settle, bool) or not isinstance(settle, (int, float)) or not settle >= 0:
        raise RealDataError(f"settle must be a non-negative number of s, got {settle!r}")
    return float(settle)


def load_enes(
    length_cm: int,
    index: int = 0,
    *,
    root: str | Path = DEFAULT_ROOT,
    duration: float | None = 5.0,
    settle: float = 0.1,
    search: float = 3.0,
    raw: bool = False,
) -> Trial:
    """Load one aluminium release record (enes-alu-release) as a trial.

    Parameters
    ----------
    length_cm : int
        Free length in cm: 30, 40, 50 or 60.
    index : int
        Which record of that length (records sorted by folder name; see
        :func:`list_real_datasets`).
    root : str or Path
        The real-data folder (see :func:`resolve_root`).
    duration : float or None
        Window length in s (None: to the end of the 20 s record).
    settle : float
        The window starts at the first sample more than ``settle`` s (default 0.1 s,
        the release transient per PROVENANCE.md) after the largest |a|.
    search : float
        The largest |a| (the release) is sought within the first ``search`` s
        (PROVENANCE.md: always within the first 0.8 s).
    raw : bool
        Return the whole record as recorded (g converted to m/s^2, nothing else: no
        baseline, no window, no declared initial state), for
        :mod:`bayesbeam.trials.preprocess` to choose and report the analysis;
        ``duration``, ``settle`` and ``search`` are then not used.

    Returns
    -------
    Trial
        Acceleration in m/s^2, baseline removed, non-uniform time stamps in s as
        recorded, beam from :func:`enes_beam`; ``meta`` records the dataset, the
        documented frequencies and tip mass, the baseline and the release time.

    Raises
    ------
    RealDataError
        If the data folder, length or index is not found, or the window does not fit.
    """
    base = resolve_root(root)
    records = _enes_records(base)
    if isinstance(length_cm, float) and length_cm.is_integer():
        length_cm = int(length_cm)
    if isinstance(length_cm, bool) or length_cm not in records:
        raise RealDataError(
            f"no enes-alu-release records for length {length_cm!r} cm under {base / ENES}; "
            f"available lengths (cm): {sorted(records)}"
        )
    files = records[length_cm]
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(files):
        raise RealDataError(
            f"index {index!r} out of range: {len(files)} record(s) at {length_cm} cm: "
            f"{[f.parent.name for f in files]}"
        )
    settle = _check_settle(settle)
    path = files[index]
    label = f"{ENES}/{path.parent.parent.name}/{path.parent.name}"
    arr = np.load(path, allow_pickle=False)
    if arr.ndim != 2 or arr.shape[0] != 2:
        raise RealDataError(f"{label}: expected an array of shape (2, N), got {arr.shape}")
    t, a_g = np.asarray(arr[0], dtype=float), np.asarray(arr[1], dtype=float)
    if not (np.all(np.isfinite(arr)) and np.all(np.diff(t) > 0)):
        raise RealDataError(f"{label}: non-finite values or non-increasing time stamps")
    # Baseline: the oscillation has decayed over most of the 20 s; the static level left
    # (0.04-0.06 g, PROVENANCE.md) is a sensor offset / orientation, not beam motion.
    if raw:
        return _raw_trial(t, a_g, enes_beam(length_cm), f"enes-alu-{length_cm}cm-{index}",
                          path, "npy [time s, acceleration g]",
                          _enes_meta(path, int(length_cm)), [])
    tail = t >= t[-1] - 2.0
    baseline_g = float(np.mean(a_g[tail]))
    a_g = a_g - baseline_g
    early = t <= t[0] + float(search)
    i_peak = int(np.argmax(np.abs(np.where(early, a_g, 0.0))))
    t_peak = float(t[i_peak])
    mask = _window_after(t, t_peak, settle, duration, label)
    deflection_cm = 4 if "4cmID" in path.parent.name else 2
    meta = _enes_meta(path, int(length_cm))
    digest = meta.pop("sha256")
    meta.update({
        "baseline_g": baseline_g,
        "baseline_note": "mean of the last 2 s of the record, subtracted",
        "release_peak_time_s": t_peak,
        "settle_s": settle,
        "window_s": [float(t[mask][0]), float(t[mask][-1])],
    })
    trial = Trial(
        times=t[mask],
        values=a_g[mask] * STANDARD_GRAVITY,
        quantity="acceleration",
        beam=enes_beam(length_cm),
        name=f"enes-alu-{length_cm}cm-{index}",
        source={
            "file": str(path),
            "sha256": digest,
            "unit": "g",
            "format": "npy [time s, acceleration g]",
            "processing": [
                f"baseline {baseline_g!r} g (mean of last 2 s) subtracted",
                f"g -> m/s^2 (x {STANDARD_GRAVITY})",
                f"window from first sample > release peak {t_peak!r} s + {settle!r} s, "
                f"duration {duration!r} s",
            ],
        },
        initial={
            "note": (
                f"hand release from about {deflection_cm} cm tip deflection at or before "
                f"{t_peak:.3f} s; state at the window start is a free vibration of several modes"
            )
        },
        meta=meta,
    )
    return trial


def _enes_meta(path: Path, length_cm: int) -> dict[str, Any]:
    """Metadata of an enes record (documented values; ``sha256`` of the file included)."""
    digest = file_sha256(path)
    deflection_cm = 4 if "4cmID" in path.parent.name else 2
    f1, f2 = _ENES_DOCUMENTED_HZ.get(length_cm, (math.nan, math.nan))
    return {
        "dataset": ENES,
        "record": path.parent.name,
        "length_cm": length_cm,
        "licence": "MIT, Copyright 2024 Enes Demirkaya (LICENSE-MIT.txt beside the data)",
        "source_repository": "EnesDemirkaya/Vibration-Tester-ADXL357-FFT",
        "source_commit": "14e12b7c1a54e64a6b5b240056880f458503f142",
        "sha256": digest,
        "sha256_matches_provenance": digest.startswith(
            _ENES_SHA256_PREFIX.get(path.parent.name, "-")
        ),
        "nominal_release_tip_deflection_m": deflection_cm / 100.0,
        "documented_tip_mass_kg": 0.01,
        "tip_mass_note": (
            "source MATLAB script Mt = 0.01 kg, README 5 g; not in the Beam (tip_mass 0). "
            "PROVENANCE: E-B with 5 g matches the measured f1"
        ),
        "sensor_note": (
            "ADXL357 Z axis 6 cm from the free end (folder names; the 30/60 cm folders "
            "say only 'at 6cm')"
        ),
        "documented_f1_hz": f1,
        "documented_f2_hz": f2,
        "nominal_E_Pa": 70e9,
        "density_kg_m3": 2700.0,
    }


def _raw_trial(t: np.ndarray, a_g: np.ndarray, beam: Beam, name: str, path: Path,
               fmt: str, meta: dict[str, Any], steps: list[str]) -> Trial:
    """Return the whole record as a trial: g -> m/s^2 and nothing else (``raw=True``)."""
    digest = meta.pop("sha256")
    return Trial(
        times=t,
        values=a_g * STANDARD_GRAVITY,
        quantity="acceleration",
        beam=beam,
        name=name,
        source={
            "file": str(path),
            "sha256": digest,
            "unit": "g",
            "format": fmt,
            "processing": [*steps, f"g -> m/s^2 (x {STANDARD_GRAVITY})"],
        },
        meta={**meta, "raw": True},
    )


def _hrshm_meta() -> dict[str, Any]:
    """Documented metadata of the steel record (PROVENANCE.md)."""
    return {
        "dataset": HRSHM,
        "record": "timeseries_data.lvm",
        "licence": "CC BY-SA 4.0 (LICENSE-CC-BY-SA-4.0.txt beside the data)",
        "citation": (
            "Puja Chowdhury, Austin Downey, Jason D. Bakos and Philip Conrad, "
            '"Dataset-4-univariate-signal-with-nonstationarity," Apr. 2021. '
            "https://github.com/High-Rate-SHM-Working-Group/"
            "Dataset-4-Univariate-signal-with-non-stationarity"
        ),
        "source_commit": "42c970f7e931e879f9179475b758267d9c12b538",
        "documented_f_hz": [6.62, 41.4, 117.5],
        "length_note": (
            "759 mm is the documented overall length; the free length is not documented "
            "and 0.759 m is used"
        ),
        "sensor_note": "accelerometer 'close to the edge': assumed at the tip",
        "material_note": "steel, grade not documented: density 7850 kg/m^3, E 200 GPa nominal",
        "attachment_note": (
            "shaker and load cell may have stayed attached near the tip (unknown mass)"
        ),
    }

def _read_lvm(path: Path) -> tuple[np.ndarray, np.ndarray, dict[str, str]]:
    """Read a 2-column LabVIEW .lvm text file (time, value) and its header fields."""
    lines = path.read_text(encoding="latin-1").splitlines()
    ends = [i for i, ln in enumerate(lines) if ln.startswith("***End_of_Header***")]
    if len(ends) < 2:
        raise RealDataError(f"{path}: expected two ***End_of_Header*** lines (LabVIEW .lvm)")
    header: dict[str, str] = {}
    for ln in lines[: ends[1]]:
        parts = ln.split("\t")
        if len(parts) >= 2 and parts[0]:
            header[parts[0]] = parts[1]
    columns = lines[ends[1] + 1].split("\t")
    if columns[:2] != ["X_Value", "Acceleration"]:
        raise RealDataError(f"{path}: unexpected column header {columns[:2]}")
    try:
        data = np.loadtxt(lines[ends[1] + 2 :], delimiter="\t", usecols=(0, 1), ndmin=2)
    except ValueError as err:
        raise RealDataError(f"{path}: could not read the data rows: {err}") from None
    return data[:, 0], data[:, 1], header


def load_hrshm(
    *,
    root: str | Path = DEFAULT_ROOT,
    duration: float | None = 10.0,
    settle: float = 0.1,
    raw: bool = False,
) -> Trial:
    """Load the steel impulse record (hrshm-steel-impulse) as a trial.

    The .lvm time column is rounded to 1 us; the stamps are regenerated as
    ``t_first + k dt`` with dt fitted by least squares (6.0546875e-4 s = 31/51200 s,
    an NI-9234 rate) after checking that they stay within 1 us of the file's.

    Parameters
    ----------
    root : str or Path
        The real-data folder (see :func:`resolve_root`).
    duration : float or None
        Window length in s (None: to the end of the 49.6 s record).
    settle : float
        The window starts at the first sample more than ``settle`` s after the impact
        peak (largest |a|), leaving out the contact and the fastest-decaying modes.
    raw : bool
        Return the whole record (stamps regenerated, g converted to m/s^2, nothing
        else), for :mod:`bayesbeam.trials.preprocess`; ``duration`` and ``settle``
        are then not used.

    Returns
    -------
    Trial
        Acceleration in m/s^2 (baseline = mean of the pre-impact samples, removed),
        uniform time stamps in s, beam from :func:`hrshm_beam`.

    Raises
    ------
    RealDataError
        If the file is missing or not as documented, or the window does not fit.
    """
    base = resolve_root(root)
    path = base / HRSHM / "timeseries_data.lvm"
    if not path.is_file():
        raise RealDataError(f"{path} not found (hrshm-steel-impulse data set)")
    settle = _check_settle(settle)
    t_file, a_g, header = _read_lvm(path)
    unit = header.get("Y_Unit_Label", "").strip()
    if unit != "g":
        raise RealDataError(f"{path}: expected Y_Unit_Label 'g', got {unit!r}")
    n_doc = header.get("Samples", "").strip()
    if n_doc and int(n_doc) != t_file.size:
        raise RealDataError(f"{path}: header says {n_doc} samples, file has {t_file.size}")
    k = np.arange(t_file.size)
    dt, t_first = np.polyfit(k, t_file - t_file[0], 1)[0], float(t_file[0])
    t = t_first + dt * k
    dev = float(np.max(np.abs(t - t_file)))
    if dev > 1e-6:
        raise RealDataError(
            f"{path}: time column deviates {dev:.2e} s from a uniform grid; expected the "
            "file's 1 us rounding only"
        )
    stamps = (f"time stamps regenerated as {t_first!r} + k * {float(dt)!r} s "
              f"(max deviation from the file {dev:.1e} s)")
    fmt = "LabVIEW lvm text (23 header lines; time s, acceleration g)"
    digest = file_sha256(path)
    if raw:
        return _raw_trial(t, a_g, hrshm_beam(), "hrshm-steel-impulse", path, fmt,
                          {**_hrshm_meta(), "sha256": digest,
                           "sha256_matches_provenance": digest == _HRSHM_SHA256,
                           "sampling_step_s": float(dt)}, [stamps])
    i_peak = int(np.argmax(np.abs(a_g)))
    t_peak = float(t[i_peak])
    # IEPE sensors are AC coupled; the quiet pre-trigger segment gives the offset.
    pre = t < t_peak - 0.05
    if np.count_nonzero(pre) < 100:
        raise RealDataError(f"{path}: too little pre-impact data for a baseline")
    baseline_g = float(np.mean(a_g[pre]))
    a_g = a_g - baseline_g
    label = f"{HRSHM}/timeseries_data.lvm"
    mask = _window_after(t, t_peak, settle, duration, label)
    meta: dict[str, Any] = {
        **_hrshm_meta(),
        "sha256_matches_provenance": digest == _HRSHM_SHA256,
        "baseline_g": baseline_g,
        "baseline_note": "mean of the samples more than 0.05 s before the impact peak",
        "impact_peak_time_s": t_peak,
        "settle_s": settle,
        "window_s": [float(t[mask][0]), float(t[mask][-1])],
        "sampling_step_s": float(dt),
    }
    return Trial(
        times=t[mask],
        values=a_g[mask] * STANDARD_GRAVITY,
        quantity="acceleration",
        beam=hrshm_beam(),
        name="hrshm-steel-impulse",
        source={
            "file": str(path),
            "sha256": digest,
            "unit": "g",
            "format": fmt,
            "processing": [
                stamps,
                f"baseline {baseline_g!r} g (pre-impact mean) subtracted",
                f"g -> m/s^2 (x {STANDARD_GRAVITY})",
                f"window from first sample > impact peak {t_peak!r} s + {settle!r} s, "
                f"duration {duration!r} s",
            ],
        },
        initial={"note": f"impulse at about {t_peak:.3f} s (not recorded); free decay after it"},
        meta=meta,
    )
