"""Physical plausibility of a beam description (bayesbeam.physics.plausible)."""

import pytest

from bayesbeam.physics.beam import Beam, BeamError, PointMass
from bayesbeam.physics.plausible import PLAUSIBLE, Finding, plausibility

# A 0.4 m aluminium strip, 50.8 x 2 mm: 2700 kg/m^3.
L, W, T = 0.4, 50.8e-3, 2e-3
M = 2700.0 * L * W * T


def _strip(**kw):
    args = {"length": L, "width": W, "thickness": T, "mass": M, "E": 70e9} | kw
    return Beam.rectangular(**args)


def _only(findings, check):
    assert [f.check for f in findings] == [check], [str(f) for f in findings]
    return findings[0]


def test_a_real_strip_is_plausible():
    assert plausibility(_strip()) == []
    assert plausibility(_strip(E=None)) == []


def test_mass_in_grams_is_an_error_that_names_the_density_and_the_slip():
    f = _only(plausibility(_strip(mass=1000 * M)), "density")
    assert f.severity == "error"
    assert "2.7e+06 kg/m^3" in f.message and "22,600" in f.message
    assert "grams" in f.message and "kg" in f.message


def test_dimensions_in_mm_give_a_density_below_foam():
    # one dimension in mm
    f = _only(plausibility(Beam.rectangular(L, 50.8, T, M)), "density")
    assert f.severity == "error" and "width or thickness given in mm" in f.message
    # both in mm: a thickness of 2 m is also more than the length
    g = plausibility(Beam.rectangular(L, 50.8, 2.0, M))
    assert [x.check for x in g] == ["density", "slenderness"]
    assert "width and thickness given in mm" in g[0].message
    assert "exceeds the length" in g[1].message and g[1].severity == "error"


@pytest.mark.parametrize("E, words", [(1e30, "above the stiffest"), (70.0, "GPa or MPa")])
def test_modulus_outside_every_solid_is_an_error(E, words):
    f = _only(plausibility(_strip(E=E)), "E")
    assert f.severity == "error" and words in f.message and "Pa" in f.message


def test_length_in_mm_is_an_error_and_a_micro_beam_a_warning():
    long = Beam(length=400.0, I=1e-9, rhoA=0.3)
    f = _only(plausibility(long), "length")
    assert f.severity == "error" and "mm" in f.message
    micro = Beam(length=2e-4, I=1e-24, rhoA=1e-8)
    assert _only(plausibility(micro), "length").severity == "warning"


def test_stubby_beam_and_heavy_tip_are_warnings():
    stubby = _only(plausibility(_strip(length=0.015, mass=M * 0.015 / L)), "slenderness")
    assert stubby.severity == "warning" and "Euler-Bernoulli" in stubby.message
    heavy = plausibility(_strip(tip_mass=150 * M))
    assert _only(heavy, "attached_mass_ratio").severity == "warning"
    spread = plausibility(_strip(tip_mass=60 * M, masses=(PointMass(0.2, 60 * M),)))
    assert _only(spread, "attached_mass_ratio").severity == "warning"
    assert plausibility(_strip(tip_mass=50 * M)) == []


def test_ranges_are_overridable_and_checked():
    gel = _strip(E=2e4)
    assert _only(plausibility(gel), "E").severity == "error"
    assert plausibility(gel, ranges={"E": (1e3, 1e12)}) == []
    assert PLAUSIBLE["E"] == (1e5, 1.2e12)  # the default is untouched
    with pytest.raises(BeamError, match="unknown plausibility ranges"):
        plausibility(gel, ranges={"modulus": (1, 2)})
    with pytest.raises(BeamError, match="0 < lo < hi"):
        plausibility(gel, ranges={"E": (1e12, 1e3)})


def test_beam_without_section_skips_the_section_checks():
    assert plausibility(Beam(length=0.4, I=3.4e-11, rhoA=0.27, E=70e9)) == []


def test_finding_severity_is_checked():
    assert str(Finding("warning", "x", "message")) == "message"
    with pytest.raises(ValueError, match="severity"):
        Finding("fatal", "x", "message")
