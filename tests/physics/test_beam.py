import numpy as np
import pytest

from bayesbeam.physics.beam import Beam, BeamError, Gradient, Segment


def test_rectangular_section_and_mass():
    b = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021)
    # I = w t^3 / 12 and rhoA = m / L for a uniform strip (exact arithmetic).
    assert b.I == pytest.approx(0.127 * 0.72e-3**3 / 12, rel=1e-15)
    assert b.rhoA == pytest.approx(0.021 / 0.3048, rel=1e-15)
    assert b.beam_mass == pytest.approx(0.021, rel=1e-15)
    assert b.sensor_x == 0.3048


def test_segments_keep_total_mass_and_set_factors():
    cut = Segment(0.05, 0.15, I=0.4, rhoA=0.4)
    b = Beam.rectangular(0.3, 0.1, 1e-3, 0.05, segments=(cut,))
    # ∫ rhoA(x) dx must equal the given mass: 0.2 m at factor 1 + 0.1 m at 0.4.
    assert b.rhoA * (0.2 + 0.1 * 0.4) == pytest.approx(0.05, rel=1e-14)
    assert b.beam_mass == pytest.approx(0.05, rel=1e-14)
    f = b.factors(np.array([0.0, 0.05, 0.1, 0.15, 0.3]))
    np.testing.assert_array_equal(f["I"], [1.0, 0.4, 0.4, 1.0, 1.0])
    np.testing.assert_array_equal(b.breakpoints, [0.05, 0.15])


def test_gradient_is_mean_preserving():
    b = Beam(length=2.0, I=1.0, rhoA=1.0, gradient=Gradient(E=-0.3))
    f = b.factors(np.array([0.0, 1.0, 2.0]))["E"]
    np.testing.assert_allclose(f, [1.15, 1.0, 0.85], rtol=1e-15)
    assert b.mean_factor("E") == pytest.approx(1.0, rel=1e-15)


def test_toml_round_trip(tmp_path):
    b = Beam.rectangular(
        0.4, 0.05, 2e-3, 0.108, E=7e10, tip_mass=0.005, root_spring=50.0,
        sensor_position=0.34, quantity="acceleration",
        segments=(Segment(0.1, 0.2, I=0.5, rhoA=0.5),), gradient=Gradient(I=0.1),
    )
    d = b.to_dict()
    text = "[beam]\n" + "\n".join(
        f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"'
        for k, v in d.items() if k not in ("segments", "gradient")
    )
    text += "\n[[beam.segments]]\nstart = 0.1\nend = 0.2\nI = 0.5\nrhoA = 0.5\n"
    text += "[beam.gradient]\nI = 0.1\n"
    p = tmp_path / "beam.toml"
    p.write_text(text)
    assert Beam.from_toml(p) == b


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"length": -1.0, "I": 1.0, "rhoA": 1.0}, "length must be a finite positive"),
        ({"length": 1.0, "I": 0.0, "rhoA": 1.0}, "I .second moment"),
        ({"length": 1.0, "I": 1.0, "rhoA": float("nan")}, "rhoA"),
        ({"length": 1.0, "I": 1.0, "rhoA": 1.0, "sensor_position": 2.0}, "beyond the free end"),
        ({"length": 1.0, "I": 1.0, "rhoA": 1.0, "quantity": "strain"}, "quantity must be"),
        ({"length": 1.0, "I": 1.0, "rhoA": 1.0, "tip_mass": -0.1}, "tip_mass"),
        (
            {"length": 1.0, "I": 1.0, "rhoA": 1.0,
             "segments": (Segment(0.1, 0.5), Segment(0.4, 0.6))},
            "overlap",
        ),
    ],
)
def test_invalid_beams_raise_clear_errors(kwargs, match):
    with pytest.raises(BeamError, match=match):
        Beam(**kwargs)


def test_from_dict_errors():
    with pytest.raises(BeamError, match="unknown beam keys"):
        Beam.from_dict({"length": 1.0, "I": 1.0, "rhoA": 1.0, "colour": "red"})
    with pytest.raises(BeamError, match="needs 'width' and 'thickness'"):
        Beam.from_dict({"length": 1.0, "mass": 0.1})
    with pytest.raises(BeamError, match="needs 'I'"):
        Beam.from_dict({"length": 1.0})
    with pytest.raises(BeamError, match="gradient E must be"):
        Gradient(E=2.5)
