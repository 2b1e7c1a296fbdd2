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
    [("", "non-empty"), ("viscous+drag", "unknown model part"), ("kv+kv", "twice"),
     ("tip_mass", "no damping law")],
)
def test_bad_model_names(name, match):
    with pytest.raises(ModelError, match=match):
        parse_model(name)
