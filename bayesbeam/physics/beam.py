"""Beam description: geometry, spanwise properties, tip mass, clamp and sensor (SI units).

A :class:`Beam` is an immutable, validated record. Every quantity is in SI units
(m, kg, Pa, m^4, kg/m, N m/rad); conversions belong to the I/O edges.

Spanwise variation (physics.md §3) is described by dimensionless factors that
multiply the reference values ``E``, ``I`` and ``rhoA``:

* piecewise-constant :class:`Segment` s (e.g. rectangular cutouts); the finite
  element mesh puts element edges on segment edges;
* a linear :class:`Gradient`, ``factor(x) = 1 + g (x / L - 1/2)``, which keeps the
  span average of the property unchanged (so ``g`` does not trade off against the
  reference value). ``g = -0.3`` means the property falls by 30 % of its mean from
  root to tip.

Both multiply: ``EI(x) = E I · e_seg(x) i_seg(x) · (1 + g_E s)(1 + g_I s)``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import read_toml

__all__ = ["Beam", "BeamError", "Gradient", "PointMass", "Segment", "QUANTITIES"]

QUANTITIES = ("displacement", "velocity", "acceleration")


class BeamError(ValueError):
    """A beam description is invalid; the message says what and how to fix it."""


def _positive(name: str, value: Any, unit: str, *, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BeamError(f"{name} must be a number in {unit}, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        need = "non-negative" if allow_zero else "positive"
        raise BeamError(f"{name} must be a finite {need} number in {unit} (SI), got {value!r}")
    return v


@dataclass(frozen=True)
class Segment:
    """Piecewise-constant property factors on ``[start, end)`` (m from the clamp).

    Parameters
    ----------
    start, end : float
        Segment edges in m, ``0 <= start < end <= L``.
    E, I, rhoA : float
        Positive factors multiplying the reference E, I and rhoA on the segment.
    """

    start: float
    end: float
    E: float = 1.0
    I: float = 1.0  # noqa: E741 - the conventional symbol for the second moment of area
    rhoA: float = 1.0

    def __post_init__(self) -> None:
        s = _positive("segment start", self.start, "m", allow_zero=True)
        e = _positive("segment end", self.end, "m")
        if e <= s:
            raise BeamError(f"segment end ({e} m) must be greater than its start ({s} m)")
        for name in ("E", "I", "rhoA"):
            _positive(f"segment factor {name}", getattr(self, name), "(dimensionless)")


@dataclass(frozen=True)
class Gradient:
    """Linear spanwise factors ``1 + g (x/L - 1/2)`` for E, I and rhoA.

    Each ``g`` must lie in (-2, 2) so the factor stays positive along the span.
    """

    E: float = 0.0
    I: float = 0.0  # noqa: E741
    rhoA: float = 0.0

    def __post_init__(self) -> None:
        for name in ("E", "I", "rhoA"):
            g = getattr(self, name)
            if not (isinstance(g, (int, float)) and math.isfinite(g) and -2.0 < g < 2.0):
                raise BeamError(
                    f"gradient {name} must be a number in (-2, 2) (factor 1 + g (x/L - 1/2) "
                    f"must stay positive), got {g!r}"
                )

    @property
    def is_zero(self) -> bool:
        """True when no property varies linearly."""
        return self.E == 0.0 and self.I == 0.0 and self.rhoA == 0.0


@dataclass(frozen=True)
class PointMass:
    """A concentrated mass attached to the span: a sensor, a cable clip, a glue blob.

    Parameters
    ----------
    position : float
        Distance from the clamp in m, ``0 <= position <= L`` (checked by :class:`Beam`).
    mass : float
        Mass in kg, >= 0.
    """

    position: float
    mass: float

    def __post_init__(self) -> None:
        _positive("point mass position", self.position, "m", allow_zero=True)
        _positive("point mass", self.mass, "kg", allow_zero=True)


@dataclass(frozen=True)
class Beam:
    """An Euler–Bernoulli cantilever clamped at x = 0 (SI units throughout).

    Parameters
    ----------
    length : float
        Free length L in m.
    I : float
        Reference second moment of area in m^4.
    rhoA : float
        Reference mass per unit length in kg/m.
    E : float or None
        Nominal Young's modulus in Pa (used where no E is given, e.g. ``modes``);
        in inference E is a parameter.
    width, thickness : float or None
        Rectangular cross-section in m, kept for the record.
    segments : tuple of Segment
        Piecewise-constant factors; must not overlap.
    gradient : Gradient
        Linear factors.
    tip_mass : float
        Concentrated mass at x = L in kg.
    tip_inertia : float
        Rotary inertia at x = L in kg m^2.
    masses : tuple of PointMass
        Known attachments on the span (sensors, cables), each a point mass at a
        position from the clamp; translational inertia only (rotary inertia of a small
        attachment is O((size/wavelength)^2) smaller).
    root_spring : float or None
        Rotational clamp stiffness k_theta in N m/rad; None means a rigid clamp.
    sensor_position : float or None
        Sensor position in m from the clamp, in (0, L]; None means the tip.
    quantity : str
        What the sensor measures: 'displacement', 'velocity' or 'acceleration'.
    """

    length: float
    I: float  # noqa: E741
    rhoA: float
    E: float | None = None
    width: float | None = None
    thickness: float | None = None
    segments: tuple[Segment, ...] = ()
    gradient: Gradient = field(default_factory=Gradient)
    tip_mass: float = 0.0
    tip_inertia: float = 0.0
    masses: tuple[PointMass, ...] = ()
    root_spring: float | None = None
    sensor_position: float | None = None
    quantity: str = "displacement"

    def __post_init__(self) -> None:
        L = _positive("length", self.length, "m")
        _positive("I (second moment of area)", self.I, "m^4")
        _positive("rhoA (mass per length)", self.rhoA, "kg/m")
        if self.E is not None:
            _positive("E (Young's modulus)", self.E, "Pa")
        for name in ("width", "thickness"):
            if getattr(self, name) is not None:
                _positive(name, getattr(self, name), "m")
        _positive("tip_mass", self.tip_mass, "kg", allow_zero=True)
        _positive("tip_inertia", self.tip_inertia, "kg m^2", allow_zero=True)
        if self.root_spring is not None:
            _positive("root_spring", self.root_spring, "N m/rad")
        if self.sensor_position is not None:
            xs = _positive("sensor_position", self.sensor_position, "m")
            if xs > L * (1 + 1e-12):
                raise BeamError(
                    f"sensor_position {xs} m lies beyond the free end (length {L} m); "
                    "give the distance from the clamp in metres"
                )
        if self.quantity not in QUANTITIES:
            raise BeamError(f"quantity must be one of {QUANTITIES}, got {self.quantity!r}")
        if not isinstance(self.gradient, Gradient):
            raise BeamError("gradient must be a Gradient (or a table with keys E, I, rhoA)")
        segs = sorted(self.segments, key=lambda s: s.start)
        for s in segs:
            if not isinstance(s, Segment):
                raise BeamError("segments must be Segment records")
            if s.end > L * (1 + 1e-12):
                raise BeamError(f"segment [{s.start}, {s.end}] m extends beyond length {L} m")
        for a, b in zip(segs, segs[1:], strict=False):
            if b.start < a.end - 1e-12 * L:
                raise BeamError(
                    f"segments [{a.start}, {a.end}] and [{b.start}, {b.end}] m overlap; "
                    "segments must be disjoint"
                )
        object.__setattr__(self, "segments", tuple(segs))
        pts = []
        for pm in self.masses:
            if isinstance(pm, dict):
                try:
                    pm = PointMass(**pm)
                except TypeError as err:
                    raise BeamError(
                        f"bad [[beam.masses]] entry {pm!r}: give 'position' (m from the "
                        f"clamp) and 'mass' (kg) ({err})"
                    ) from None
            if not isinstance(pm, PointMass):
                raise BeamError("masses must be PointMass records (position m, mass kg)")
            if pm.position > L * (1 + 1e-12):
                raise BeamError(
                    f"point mass at {pm.position} m lies beyond the free end (length {L} m); "
                    "give the distance from the clamp in metres"
                )
            pts.append(pm)
        object.__setattr__(self, "masses", tuple(sorted(pts, key=lambda m: m.position)))

    # -- constructors -------------------------------------------------------------
    @classmethod
    def rectangular(
        cls, length: float, width: float, thickness: float, mass: float, **kw: Any
    ) -> Beam:
        """Build a beam of rectangular section from its dimensions and total mass.

        Parameters
        ----------
        length, width, thickness : float
            Dimensions in m.
        mass : float
            Mass of the beam itself in kg (tip mass excluded). With segments or a
            rhoA gradient the reference rhoA is chosen so that ∫ rhoA(x) dx = mass.
        **kw
            Other :class:`Beam` fields (E, segments, gradient, tip_mass, ...).

        Returns
        -------
        Beam
        """
        L = _positive("length", length, "m")
        w = _positive("width", width, "m")
        t = _positive("thickness", thickness, "m")
        m = _positive("mass", mass, "kg")
        probe = cls(length=L, I=w * t**3 / 12.0, rhoA=1.0, width=w, thickness=t, **kw)
        mean_r = probe.mean_factor("rhoA")
        return dataclasses.replace(probe, rhoA=m / (L * mean_r))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Beam:
        """Build a beam from a mapping (the ``[beam]`` table of a TOML file).

        Either ``width``, ``thickness`` and ``mass``, or ``I`` and ``rhoA`` must be
        given. Optional keys: ``E``, ``tip_mass``, ``tip_inertia``, ``root_spring``,
        ``sensor_position``, ``quantity``, ``segments`` (list of tables with
        ``start``, ``end`` and factors ``E``, ``I``, ``rhoA``), ``gradient``
        (table with ``E``, ``I``, ``rhoA``) and ``masses`` (list of tables with
        ``position`` in m from the clamp and ``mass`` in kg; ``[[beam.masses]]`` in TOML).

        Parameters
        ----------
        d : dict
            The description, SI units.

        Returns
        -------
        Beam
        """
        d = dict(d)
        known = {f.name for f in dataclasses.fields(cls)} | {"mass"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise BeamError(
                f"unknown beam keys {unknown}; allowed: {sorted(known)} (SI units: m, kg, Pa)"
            )
        if "length" not in d:
            raise BeamError("beam description needs 'length' (m)")
        try:
            segs = tuple(Segment(**s) for s in d.pop("segments", ()))
            grad = Gradient(**d.pop("gradient", {}))
        except TypeError as err:
            raise BeamError(f"bad segment or gradient table: {err}") from None
        if "mass" in d:
            for key in ("width", "thickness"):
                if key not in d:
                    raise BeamError(f"'mass' needs 'width' and 'thickness' too; '{key}' is missing")
            if "I" in d or "rhoA" in d:
                raise BeamError("give either width/thickness/mass or I/rhoA, not both")
            return cls.rectangular(segments=segs, gradient=grad, **d)
        for key in ("I", "rhoA"):
            if key not in d:
                raise BeamError(
                    f"beam description needs '{key}' (or width, thickness and mass instead)"
                )
        return cls(segments=segs, gradient=grad, **d)

    @classmethod
    def from_toml(cls, path: str | Path) -> Beam:
        """Read a beam from a TOML file (its ``[beam]`` table, or the top level).

        Parameters
        ----------
        path : str or Path
            The TOML file.

        Returns
        -------
        Beam
        """
        doc = read_toml(path, what="beam file", error=BeamError)
        return cls.from_dict(doc.get("beam", doc))

    def to_dict(self) -> dict[str, Any]:
        """Return a TOML-friendly mapping that :meth:`from_dict` reads back.

        Returns
        -------
        dict
        """
        out: dict[str, Any] = {"length": self.length, "I": self.I, "rhoA": self.rhoA}
        for name in ("E", "width", "thickness", "root_spring", "sensor_position"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        out["tip_mass"] = self.tip_mass
        out["tip_inertia"] = self.tip_inertia
        out["quantity"] = self.quantity
        if self.segments:
            out["segments"] = [dataclasses.asdict(s) for s in self.segments]
        if self.masses:
            out["masses"] = [dataclasses.asdict(m) for m in self.masses]
        if not self.gradient.is_zero:
            out["gradient"] = dataclasses.asdict(self.gradient)
        return out

    def replace(self, **changes: Any) -> Beam:
        """Return a copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    # -- spanwise properties ------------------------------------------------------
    @property
    def sensor_x(self) -> float:
        """Sensor position in m (the tip when none is given)."""
        return self.length if self.sensor_position is None else float(self.sensor_position)

    @property
    def breakpoints(self) -> np.ndarray:
        """Sorted segment edges strictly inside (0, L), shape (k,), in m."""
        edges = {e for s in self.segments for e in (s.start, s.end)}
        L = self.length
        return np.array(sorted(e for e in edges if 1e-12 * L < e < L * (1 - 1e-12)))

    def factors(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """Dimensionless spanwise factors of E, I and rhoA at positions ``x``.

        Parameters
        ----------
        x : ndarray, shape (n,)
            Positions in m from the clamp. At a segment edge the segment that
            starts there applies.

        Returns
        -------
        dict of str to ndarray, shape (n,)
            Keys 'E', 'I', 'rhoA'.
        """
        x = np.asarray(x, dtype=float)
        s = x / self.length - 0.5
        out = {n: 1.0 + getattr(self.gradient, n) * s for n in ("E", "I", "rhoA")}
        for seg in self.segments:
            inside = (x >= seg.start) & (x < seg.end)
            if seg.end >= self.length * (1 - 1e-12):
                inside |= x >= seg.start
            for n in ("E", "I", "rhoA"):
                out[n] = np.where(inside, out[n] * getattr(seg, n), out[n])
        return out

    def mean_factor(self, name: str) -> float:
        """Span average of a property factor ('E', 'I' or 'rhoA'), exact for these profiles."""
        # Piecewise linear on the pieces between breakpoints: the midpoint rule is exact.
        edges = np.concatenate(([0.0], self.breakpoints, [self.length]))
        mids = 0.5 * (edges[1:] + edges[:-1])
        return float(np.sum(self.factors(mids)[name] * np.diff(edges)) / self.length)

    @property
    def beam_mass(self) -> float:
        """Mass of the beam itself in kg, ∫ rhoA(x) dx (tip mass and attachments excluded)."""
        return self.rhoA * self.length * self.mean_factor("rhoA")
