"""Model names: damping laws and extensions joined by '+'.

A model is the set of damping laws (physics.md §1) plus optional extensions from
the diagnosis catalogue (physics.md §3). Its name joins the parts with '+' in a
canonical order, e.g. ``viscous+kv`` or ``viscous+kv+tip_mass``.

Physical parameter names (SI units):

============  ===========  ===============================================
name          unit         meaning
============  ===========  ===============================================
E             Pa           Young's modulus (reference value)
gamma         kg/(m s)     viscous (air) damping per unit length
c_d           Pa s         Kelvin–Voigt strain-rate damping, moment c_d I w_xxt
a             N s          spatial-hysteresis strength (Banks–Inman)
b             m            spatial-hysteresis kernel width (Gaussian sd)
tip_mass      kg           concentrated tip mass added to the beam's own
added_mass    kg           concentrated mass at added_mass_position
added_mass_position  m     its distance from the clamp, in [0, L]
root_spring   N m/rad      rotational clamp stiffness k_theta
stiffness_gradient  1      EI(x) factor 1 + g (x/L - 1/2)
drag          kg/m²        quadratic air drag per unit length, force -c_q |w_t| w_t
friction      N            dry (Coulomb) clamp friction on the first mode
f1_slope      Hz/m         change of the first natural frequency per m of its tip
                           amplitude (negative: softening)
============  ===========  ===============================================
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LAWS", "NOISE", "NONLINEAR", "STRUCTURAL", "Model", "ModelError", "parse_model"]

#: Damping laws and their parameters (physics.md §1).
LAWS: dict[str, tuple[str, ...]] = {"viscous": ("gamma",), "kv": ("c_d",), "sh": ("a", "b")}
#: Structural extensions that change M or K (physics.md §3).
STRUCTURAL: dict[str, tuple[str, ...]] = {
    "tip_mass": ("tip_mass",),
    "added_mass": ("added_mass", "added_mass_position"),
    "root_spring": ("root_spring",),
    "stiffness_gradient": ("stiffness_gradient",),
}
#: Extensions that act on the nonlinear dynamics (physics.md §3): amplitude-dependent
#: damping (quadratic air drag, dry clamp friction) and an amplitude-dependent first
#: natural frequency, each a cause of its own.
NONLINEAR: dict[str, tuple[str, ...]] = {
    "drag": ("drag",), "friction": ("friction",), "amplitude_stiffness": ("f1_slope",),
}
#: Former model parts and what replaced them (named in the error message).
_RENAMED: dict[str, str] = {
    "amplitude_damping": "was split into 'drag' (quadratic air drag) and 'friction' (dry "
                         "clamp friction); use either or both, e.g. 'viscous+kv+drag+friction'",
}
#: Extensions of the noise / observation model.
NOISE: dict[str, tuple[str, ...]] = {"ar1_noise": ("rho",), "sensor_offset": ("offset",)}

_ORDER = list(LAWS) + list(STRUCTURAL) + list(NONLINEAR) + list(NOISE)


class ModelError(ValueError):
    """A model name is invalid."""


@dataclass(frozen=True)
class Model:
    """A damping model with optional extensions.

    Parameters
    ----------
    parts : tuple of str
        Law and extension names in canonical order.
    """

    parts: tuple[str, ...]

    @property
    def name(self) -> str:
        """Canonical name, parts joined by '+'."""
        return "+".join(self.parts)

    @property
    def laws(self) -> tuple[str, ...]:
        """The damping laws present."""
        return tuple(p for p in self.parts if p in LAWS)

    @property
    def structural(self) -> tuple[str, ...]:
        """The structural extensions present."""
        return tuple(p for p in self.parts if p in STRUCTURAL)

    @property
    def nonlinear(self) -> tuple[str, ...]:
        """The nonlinear extensions present."""
        return tuple(p for p in self.parts if p in NONLINEAR)

    @property
    def noise(self) -> tuple[str, ...]:
        """The noise-model extensions present."""
        return tuple(p for p in self.parts if p in NOISE)

    @property
    def physical_params(self) -> tuple[str, ...]:
        """Names of the parameters of the forward model, E first."""
        names = ["E"]
        for p in self.parts:
            if p in LAWS:
                names += LAWS[p]
            elif p in STRUCTURAL:
                names += STRUCTURAL[p]
            elif p in NONLINEAR:
                names += NONLINEAR[p]
        return tuple(names)

    @property
    def noise_params(self) -> tuple[str, ...]:
        """Names of the observation-model parameters besides sigma."""
        return tuple(n for p in self.parts if p in NOISE for n in NOISE[p])

    def extend(self, part: str) -> Model:
        """Return the model with one more law or extension.

        Parameters
        ----------
        part : str
            A law or extension name.

        Returns
        -------
        Model
        """
        return parse_model(self.name + "+" + part)

    def __str__(self) -> str:
        return self.name


def parse_model(name: str | Model) -> Model:
    """Parse a model name such as ``'viscous+kv'``.

    Parameters
    ----------
    name : str or Model
        Parts joined by '+'; order does not matter, duplicates are an error.

    Returns
    -------
    Model
        With parts in canonical order.
    """
    if isinstance(name, Model):
        return name
    if not isinstance(name, str) or not name.strip():
        raise ModelError(f"model name must be a non-empty string like 'viscous+kv', got {name!r}")
    parts = [p.strip() for p in name.split("+")]
    renamed = [p for p in parts if p in _RENAMED]
    if renamed:
        raise ModelError(f"model part {renamed[0]!r} in {name!r} {_RENAMED[renamed[0]]}")
    unknown = [p for p in parts if p not in _ORDER]
    if unknown:
        raise ModelError(
            f"unknown model part(s) {unknown} in {name!r}; laws: {list(LAWS)}, "
            f"extensions: {list(STRUCTURAL) + list(NONLINEAR) + list(NOISE)}"
        )
    if len(set(parts)) != len(parts):
        raise ModelError(f"model {name!r} names a part twice")
    if not any(p in LAWS for p in parts):
        raise ModelError(f"model {name!r} has no damping law; add one of {list(LAWS)}")
    return Model(tuple(sorted(parts, key=_ORDER.index)))
