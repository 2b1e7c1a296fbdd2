import pytest

from bayesbeam.physics.forward import initial_names
from bayesbeam.physics.models import (
    LAWS,
    NOISE,
    NONLINEAR,
    SIGNAL,
    STRUCTURAL,
    ModelError,
    parameter_units,
    parse_model,
)


def test_canonical_names_and_parameters():
    m = parse_model("sh+viscous")
    assert m.name == "viscous+sh"
    assert m.physical_params == ("E", "gamma", "a", "b")
    assert parse_model("viscous+kv+sh").physical_params == ("E", "gamma", "c_d", "a", "b")
    ext = parse_model("viscous+kv").extend("tip_mass").extend("ar1_noise")
    assert ext.name == "viscous+kv+tip_mass+ar1_noise"
    assert ext.physical_params == ("E", "gamma", "c_d", "tip_mass")
    assert ext.noise_params == ("rho",)


@pytest.mark.parametrize(
    ("name", "match"),
    [("", "non-empty"), ("viscous+magnet", "unknown model part"), ("kv+kv", "twice"),
     ("viscous+kv+amplitude_damping", "split into 'drag'.*and 'friction'"),
     ("tip_mass", "no damping law")],
)
def test_bad_model_names(name, match):
    with pytest.raises(ModelError, match=match):
        parse_model(name)


def test_drag_and_friction_are_separate_parts():
    # Either or both; each adds its own parameter (physics.md §3).
    assert parse_model("viscous+kv+drag").physical_params == ("E", "gamma", "c_d", "drag")
    assert parse_model("viscous+kv+friction").physical_params == ("E", "gamma", "c_d",
                                                                   "friction")
    both = parse_model("friction+viscous+drag+kv")
    assert both.name == "viscous+kv+drag+friction"
    assert both.nonlinear == ("drag", "friction")
    assert both.physical_params == ("E", "gamma", "c_d", "drag", "friction")


def test_every_parameter_name_has_a_unit():
    # Every name a model can sample or report: the parts' parameters, eta (sampled in
    # place of a), the initial conditions and the noise parameters.
    names = {n for table in (LAWS, STRUCTURAL, NONLINEAR, NOISE) for ps in table.values()
             for n in ps}
    names |= {"eta", "sigma"} | {n for kind in ("release", "impulse", "modes:3")
                                 for n in initial_names(kind)}
    for name in sorted(names):
        unit, meaning = parameter_units(name, "m/s")
        assert unit and meaning and unit != SIGNAL, name
    assert parameter_units("E") == ("Pa", "Young's modulus (reference value)")
    assert parameter_units("c_d")[0] == "Pa s"
    assert parameter_units("gamma")[0] == "kg/(m s)"
    assert parameter_units("A2")[0] == parameter_units("B2")[0] == "m"
    # the signal's unit: only with the trial's quantity
    assert parameter_units("sigma", "m/s^2")[0] == "m/s^2"
    assert parameter_units("offset")[0] == SIGNAL
    with pytest.raises(KeyError, match="no unit known for parameter 'zeta'"):
        parameter_units("zeta")
    assert parameter_units("zeta", default=("", "")) == ("", "")
