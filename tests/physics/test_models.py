import pytest

from bayesbeam.physics.models import ModelError, parse_model


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
