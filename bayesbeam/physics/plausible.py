"""Physical plausibility of a beam description: unit slips caught before any fit.

A :class:`~bayesbeam.physics.beam.Beam` is valid when its numbers are finite and
positive; it is *plausible* when they describe a beam that can exist. A mass typed in
grams, a length in millimetres or a modulus in GPa gives a valid beam that no material
makes, and a fit of it returns confident nonsense. :func:`plausibility` compares the
description with the ranges of :data:`PLAUSIBLE` and returns :class:`Finding` s:

* **errors** — a value outside what any solid gives, most likely a unit slip; the
  message names the value, the range and the slip that would explain it;
* **warnings** — a description that can exist but where the model is questionable
  (a stubby beam, a beam that is a spring under a far heavier mass, a micro-beam).

The command line refuses errors unless ``--skip-checks`` (then they are warnings too).
SI units throughout (m, kg, Pa).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bayesbeam.physics.beam import Beam, BeamError

__all__ = ["PLAUSIBLE", "Finding", "plausibility"]

#: Plausible ranges of a beam description (SI units); override per key with
#: ``plausibility(beam, ranges={...})``.
#:
#: * ``density`` (kg/m^3): 10 (the lightest rigid polymer foams, e.g. expanded
#:   polystyrene 10-30 kg/m^3) to 22,600 (osmium, the densest element, 22,590 kg/m^3;
#:   CRC Handbook of Chemistry and Physics). Checked as ``rhoA / (width × thickness)``
#:   when both are given.
#: * ``E`` (Pa): 1e5 (soft silicone elastomers, ~0.1-1 MPa) to 1.2e12 (diamond,
#:   1.05-1.2 TPa); Ashby, *Materials Selection in Mechanical Design*, 4th ed. 2011,
#:   the modulus-density chart.
#: * ``length`` (m): 1 mm to 200 m. Above: a length in mm read as m (an error). Below:
#:   a micro-cantilever (a warning: the model holds, but check the unit).
#: * ``slenderness`` (-): the least ``length / thickness`` for Euler-Bernoulli theory.
#:   Shear deformation and rotary inertia, which the model neglects, lower the first
#:   frequency of a cantilever by O((h/L)^2), about 1 % at L/h = 10 and far more for
#:   the higher modes (Timoshenko, *Vibration Problems in Engineering*; Han, Benaroya
#:   & Wei 1999, J. Sound Vib. 225, 935-988). Below it: a warning; below 1 (thicker
#:   than long): an error.
#: * ``attached_mass_ratio`` (-): the largest (tip + point masses) / beam mass. Above
#:   it the beam is a massless spring under a lumped mass: its distributed properties
#:   hardly show in the record (a warning; it is also what masses typed in grams on a
#:   beam given in kg look like).
PLAUSIBLE: dict[str, Any] = {
    "density": (10.0, 22_600.0),
    "E": (1e5, 1.2e12),
    "length": (1e-3, 200.0),
    "slenderness": 10.0,
    "attached_mass_ratio": 100.0,
}


@dataclass(frozen=True)
class Finding:
    """One result of a sanity check: an error (refuse) or a warning (go on, say it).

    Attributes
    ----------
    severity : str
        ``"error"`` (implausible: most likely a unit or column mistake) or
        ``"warning"`` (possible, but the result may mislead).
    check : str
        The check that found it (e.g. ``"density"``, ``"E"``, ``"mode_line"``).
    message : str
        One line: what is wrong, the value, the expected range and how to fix it.
    """

    severity: str
    check: str
    message: str

    def __post_init__(self) -> None:
        if self.severity not in ("error", "warning"):
            raise ValueError(f"severity must be 'error' or 'warning', got {self.severity!r}")

    def __str__(self) -> str:
        return self.message


def _ranges(ranges: Mapping[str, Any] | None) -> dict[str, Any]:
    out = dict(PLAUSIBLE)
    if ranges:
        unknown = sorted(set(ranges) - set(PLAUSIBLE))
        if unknown:
            raise BeamError(f"unknown plausibility ranges {unknown}; known: {sorted(PLAUSIBLE)}")
        out.update(ranges)
    for key in ("density", "E", "length"):
        lo, hi = (float(v) for v in out[key])
        if not 0 < lo < hi:
            raise BeamError(f"plausibility range {key} must be (lo, hi) with 0 < lo < hi, "
                            f"got {out[key]!r}")
    return out


def _density(beam: Beam, lo: float, hi: float) -> list[Finding]:
    if beam.width is None or beam.thickness is None:
        return []
    rho = beam.rhoA / (beam.width * beam.thickness)
    if lo <= rho <= hi:
        return []
    what = (f"mass {beam.beam_mass:.3g} kg gives a density of {rho:.3g} kg/m^3 (rhoA "
            f"{beam.rhoA:.3g} kg/m over width x thickness {beam.width:g} x {beam.thickness:g} m)")
    if rho > hi:
        hint = ("was it given in grams? mass is in kg" if lo <= rho / 1e3 <= hi
                else "check mass (kg) and width, thickness (m)")
        return [Finding("error", "density", f"{what}, above the densest metal (osmium, "
                                            f"{hi:,.0f} kg/m^3); {hint}")]
    if lo <= rho * 1e3 <= hi:
        hint = "was width or thickness given in mm? lengths are in m"
    elif lo <= rho * 1e6 <= hi:
        hint = "were width and thickness given in mm? lengths are in m"
    else:
        hint = "check mass (kg) and width, thickness (m)"
    return [Finding("error", "density", f"{what}, below the lightest foams ({lo:g} kg/m^3); "
                                        f"{hint}")]


def _modulus(beam: Beam, lo: float, hi: float) -> list[Finding]:
    E = beam.E
    if E is None or lo <= E <= hi:
        return []
    if E > hi:
        return [Finding("error", "E", f"E {E:.3g} Pa is above the stiffest solid (diamond, "
                                      f"{hi:.3g} Pa); E is in Pa (70e9 for aluminium, "
                                      "200e9 for steel)")]
    return [Finding("error", "E", f"E {E:.3g} Pa is below the softest elastomers ({lo:.3g} "
                                  "Pa); was it given in GPa or MPa? E is in Pa (70e9 for "
                                  "aluminium, 200e9 for steel)")]


def _length(beam: Beam, lo: float, hi: float) -> list[Finding]:
    L = beam.length
    if L > hi:
        return [Finding("error", "length", f"length {L:g} m is above {hi:g} m; was it given "
                                           "in mm? lengths are in m")]
    if L < lo:
        return [Finding("warning", "length", f"length {L:g} m is below {lo * 1e3:g} mm: a "
                                             "micro-cantilever? lengths are in m")]
    return []


def _slenderness(beam: Beam, least: float) -> list[Finding]:
    if beam.thickness is None:
        return []
    ratio = beam.length / beam.thickness
    if ratio < 1.0:
        return [Finding("error", "slenderness",
                        f"thickness {beam.thickness:g} m exceeds the length {beam.length:g} m "
                        "(a block, not a beam); check both are in m and not swapped")]
    if ratio < least:
        return [Finding("warning", "slenderness",
                        f"length / thickness = {ratio:.3g} < {least:g}: Euler-Bernoulli theory "
                        "(no shear deformation, no rotary inertia) is questionable; expect E "
                        "biased low, the more so from the higher modes")]
    return []


def _attached(beam: Beam, most: float) -> list[Finding]:
    attached = beam.tip_mass + sum(m.mass for m in beam.masses)
    ratio = attached / beam.beam_mass
    if ratio <= most:
        return []
    return [Finding("warning", "attached_mass_ratio",
                    f"tip and attached masses ({attached:.3g} kg) are {ratio:.3g} x the "
                    f"beam's own mass ({beam.beam_mass:.3g} kg): the beam acts as a spring "
                    "under a lumped mass and its distributed damping is hardly identifiable; "
                    "check that every mass is in kg")]


def plausibility(beam: Beam, ranges: Mapping[str, Any] | None = None) -> list[Finding]:
    """Compare a beam description with physically plausible values (see :data:`PLAUSIBLE`).

    Parameters
    ----------
    beam : Beam
        The description (SI units).
    ranges : mapping, optional
        Keys of :data:`PLAUSIBLE` to override, e.g. ``{"E": (1e3, 1e12)}`` for a gel
        or ``{"length": (1e-5, 200.0)}`` for a micro-cantilever.

    Returns
    -------
    list of Finding
        Errors (likely unit slips: density, E, length above its range, a beam thicker
        than long) and warnings (a short, micro or mass-loaded beam); empty when
        plausible.

    Raises
    ------
    BeamError
        For an unknown key or an invalid range in ``ranges``.
    """
    r = _ranges(ranges)
    out = _density(beam, *r["density"])
    out += _modulus(beam, *r["E"])
    out += _length(beam, *r["length"])
    out += _slenderness(beam, float(r["slenderness"]))
    out += _attached(beam, float(r["attached_mass_ratio"]))
    return out
