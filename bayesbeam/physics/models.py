"""Model names: damping laws and extensions joined by '+'.

A model is the set of damping laws (physics.md §1) plus optional extensions from
the diagnosis catalogue (physics.md §3). Its name joins the parts with '+' in a
canonical order, e.g. ``viscous+kv`` or ``viscous+kv+tip_mass``.

Every parameter name a model can sample or report has its SI unit and meaning in one
table, :data:`PARAMETER_UNITS` (E in Pa, gamma in kg/(m s), c_d in Pa s, ...), read
by :func:`parameter_units`; the ArviZ trees of the fits take their ``units`` and
``long_name`` attributes from it.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "LAWS", "NOISE", "NONLINEAR", "PARAMETER_UNITS", "SIGNAL", "STRUCTURAL", "Model",
    "ModelError", "parameter_units", "parse_model",
]

#: Damping laws and their parameters (physics.md §1).
LAWS: dict[str, tuple[str, ...]] = {"viscous": ("gamma",), "kv": ("c_d",), "sh": ("a", "b")}
#: Structural extensions that change M or K (physics.md §3).
STRUCTURAL: dict[str, tuple[str, ...]] = {
    "tip_mass": ("tip_mass",),
    "added_mass": ("added_mass", "added_mass_position"),
    "root_spring": ("root_spring",),
    "stiffness_gradient": ("stiffness_gradient",),
}
#: Amplitude-dependent extensions, whose signal is not linear in the initial amplitudes
#: (bayesbeam.physics.nonlinear): the nonlinear dynamics of physics.md §3
#: (amplitude-dependent damping by quadratic air drag or dry clamp friction, an
#: amplitude-dependent first natural frequency) and a sensor whose reading is
#: quadratic in what it measures, each a cause of its own.
NONLINEAR: dict[str, tuple[str, ...]] = {
    "drag": ("drag",), "friction": ("friction",), "amplitude_stiffness": ("f1_slope",),
    "sensor_quadratic": ("k2",),
}
#: Former model parts and what replaced them (named in the error message).
_RENAMED: dict[str, str] = {
    "amplitude_damping": "was split into 'drag' (quadratic air drag) and 'friction' (dry "
                         "clamp friction); use either or both, e.g. 'viscous+kv+drag+friction'",
}
#: Extensions of the noise / observation model.
NOISE: dict[str, tuple[str, ...]] = {"ar1_noise": ("rho",), "sensor_offset": ("offset",)}

#: Placeholder unit in :data:`PARAMETER_UNITS`: the SI unit of the trial's measured
#: quantity (m, m/s or m/s^2), known only with the trial (:func:`parameter_units`).
SIGNAL = "<signal>"

#: Name -> (SI unit, meaning) of every parameter a model samples or reports: the
#: physical parameters of the parts above, the spatial-hysteresis strength ``eta`` that
#: :mod:`bayesbeam.inference.problem` samples in place of ``a``, the initial conditions of
#: :func:`bayesbeam.physics.forward.initial_names` (``A<k>``, ``B<k>``: see
#: :func:`parameter_units`) and the noise parameters. Units are written in ASCII with
#: ``^`` for powers and a space for products, as in the trial files.
PARAMETER_UNITS: dict[str, tuple[str, str]] = {
    "E": ("Pa", "Young's modulus (reference value)"),
    "gamma": ("kg/(m s)", "viscous (air) damping per unit length"),
    "c_d": ("Pa s", "Kelvin-Voigt strain-rate damping (moment c_d I w_xxt)"),
    "a": ("N s", "spatial-hysteresis strength (Banks-Inman)"),
    "eta": ("N s m^2", "spatial-hysteresis strength as the Kelvin-Voigt c_d I of equal "
                       "first-mode damping"),
    "b": ("m", "spatial-hysteresis kernel width (Gaussian sd)"),
    "tip_mass": ("kg", "concentrated tip mass added to the beam's own"),
    "added_mass": ("kg", "concentrated mass at added_mass_position"),
    "added_mass_position": ("m", "distance of added_mass from the clamp, in [0, L]"),
    "added_mass_tip_distance": ("m", "distance of added_mass from the free end (a joint "
                                     "fit's shared value over trials of different length)"),
    "root_spring": ("N m/rad", "rotational clamp stiffness k_theta"),
    "stiffness_gradient": ("1", "EI(x) factor 1 + g (x/L - 1/2)"),
    "drag": ("kg/m^2", "quadratic air drag per unit length (force -c_q |w_t| w_t)"),
    "friction": ("N", "dry (Coulomb) clamp friction on the first mode"),
    "f1_slope": ("Hz/m", "change of the first natural frequency per m of its tip amplitude "
                         "(negative: softening)"),
    "k2": (f"1/{SIGNAL}", "second-order sensor nonlinearity: the sensor reads y + k2 y^2 "
                            "(K2 of the IEEE Std 1293 accelerometer model)"),
    "w0": ("m", "initial tip deflection of a release"),
    "p0": ("N s", "tip impulse from rest"),
    "sigma": (SIGNAL, "noise standard deviation (marginal, for AR(1) noise)"),
    "rho": ("1", "lag-one correlation of the AR(1) noise"),
    "offset": (SIGNAL, "constant sensor offset"),
}


def parameter_units(
    name: str, signal_unit: str | None = None, *, default: tuple[str, str] | None = None,
) -> tuple[str, str]:
    """SI unit and meaning of a parameter name (:data:`PARAMETER_UNITS`).

    Parameters
    ----------
    name : str
        A name of :data:`PARAMETER_UNITS`, or ``A<k>`` / ``B<k>`` (the displacement and
        velocity/ω amplitudes of mode k at the sensor of the ``modes:K`` initial
        condition, m).
    signal_unit : str, optional
        SI unit of the trial's measured quantity (``"m"``, ``"m/s"`` or ``"m/s^2"``),
        the unit of ``sigma`` and ``offset`` (and the inverse unit of ``k2``); without it
        their units read :data:`SIGNAL`.
    default : tuple of str, optional
        Returned for a name not in the table (instead of the error).

    Returns
    -------
    unit : str
        ``"1"`` for a dimensionless parameter.
    meaning : str
        A short description (an ArviZ ``long_name``).

    Raises
    ------
    KeyError
        For a name not in the table, without ``default``.
    """
    if name.endswith("]") and "[" in name:
        # A joint fit's per-trial name, NAME[TRIAL] (bayesbeam.inference.joint).
        base, label = name[:-1].split("[", 1)
        if base.endswith("_z"):
            return "1", f"standardised deviate of {base[:-2]} of trial {label} (population)"
        unit, meaning = parameter_units(base, signal_unit, default=default or ("", ""))
        return unit, (f"{meaning} (trial {label})" if meaning else "")
    for suffix, what in (("_median", "population median of"), ("_spread", "population sd of "
                                                                "the log of")):
        if name.endswith(suffix) and name[: -len(suffix)] in PARAMETER_UNITS:
            unit, meaning = PARAMETER_UNITS[name[: -len(suffix)]]
            if suffix == "_spread":
                return "1", f"{what} {name[: -len(suffix)]} over the trials"
            return unit, f"{what} {name[: -len(suffix)]} over the trials ({meaning})"
    if name[:1] in ("A", "B") and name[1:].isdigit():
        what = "displacement" if name[0] == "A" else "velocity/omega"
        return "m", f"{what} amplitude of mode {name[1:]} at the sensor (initial condition)"
    if name not in PARAMETER_UNITS:
        if default is not None:
            return default
        raise KeyError(f"no unit known for parameter {name!r}; add it to PARAMETER_UNITS "
                       "(bayesbeam.physics.models)")
    unit, meaning = PARAMETER_UNITS[name]
    if SIGNAL in unit and signal_unit is not None:
        inverse = unit.startswith("1/") and "/" in signal_unit  # 1/(m/s^2), not 1/m/s^2
        unit = unit.replace(SIGNAL, f"({signal_unit})" if inverse else signal_unit)
    return unit, meaning


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
