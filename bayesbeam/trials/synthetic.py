"""Synthetic trials from the package's own forward model (for tests, studies and users)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward, ForwardError
from bayesbeam.physics.models import parse_model
from bayesbeam.trials.io import write_trial
from bayesbeam.trials.trial import Trial

__all__ = ["simulate_signal", "simulate_trial"]


def simulate_signal(
    beam: Beam,
    model: str,
    params: dict[str, float],
    times: np.ndarray,
    *,
    n_elements: int = 16,
    initial: str = "release",
) -> np.ndarray:
    """Noise-free sensor signal of one parameter set.

    Parameters
    ----------
    beam : Beam
    model : str
        Model name, e.g. ``'viscous+kv'``.
    params : dict
        Physical and initial-condition parameters (SI), e.g. ``E``, ``gamma``, ``w0``;
        ``E`` defaults to ``beam.E``.
    times : ndarray, shape (T,)
        Sample times in s; the initial condition holds at ``times[0]``.
    n_elements : int
    initial : str
        See :class:`bayesbeam.physics.forward.Forward`.

    Returns
    -------
    ndarray, shape (T,)
        Signal in SI units of ``beam.quantity``.
    """
    if parse_model(model).nonlinear:
        from bayesbeam.physics.nonlinear import NonlinearForward

        fwd = NonlinearForward(beam, model, times, n_elements=n_elements, initial=initial)
    else:
        fwd = Forward(beam, model, times, n_elements=n_elements, initial=initial)
    p = dict(params)
    if "E" not in p and beam.E is not None:
        p["E"] = beam.E
    missing = [n for n in fwd.param_names if n not in p]
    if missing:
        raise ForwardError(f"model {fwd.model.name!r} needs {missing} (SI units)")
    extra = sorted(set(p) - set(fwd.param_names))
    if extra:
        raise ForwardError(
            f"parameters {extra} are not part of model {fwd.model.name!r} "
            f"(it takes {list(fwd.param_names)})"
        )
    res = fwd.simulate(p)
    if not res.valid[0]:
        raise ForwardError(f"parameters outside their admissible range: {params}")
    return res.y[0]


def simulate_trial(
    beam: Beam | str | Path,
    model: str,
    params: dict[str, float],
    *,
    duration: float = 5.0,
    dt: float = 0.003906,
    tip_deflection: float = 0.005,
    noise_sd: float = 0.0,
    seed: int | None = 0,
    n_elements: int = 16,
    name: str = "synthetic",
    out: str | Path | None = None,
) -> Trial:
    """Simulate a release test and optionally write it as a trial (TOML + CSV).

    Parameters
    ----------
    beam : Beam or path
        Beam description (or a TOML file with a ``[beam]`` table).
    model : str
        Model name.
    params : dict
        Physical parameters in SI units (``E`` defaults to ``beam.E``).
    duration, dt : float
        Record length and sample interval in s.
    tip_deflection : float
        Static tip deflection at release in m.
    noise_sd : float
        Standard deviation of added white Gaussian noise, SI units of the quantity.
    seed : int or None
        Seed of the noise generator (same seed, same noise).
    n_elements : int
    name : str
    out : path, optional
        Where to write the trial TOML.

    Returns
    -------
    Trial
        Its ``meta["synthetic"]`` (written to the file's ``[meta.synthetic]`` table) records
        the generator: model, true ``params`` (SI), ``noise_sd``, ``n_elements`` and ``seed``.
    """
    if not isinstance(beam, Beam):
        beam = Beam.from_toml(beam)
    for label, v in (("duration", duration), ("dt", dt)):
        if not (np.isfinite(v) and v > 0):
            raise ForwardError(f"{label} must be a positive number of seconds, got {v}")
    if not (np.isfinite(noise_sd) and noise_sd >= 0):
        raise ForwardError(f"noise_sd must be >= 0 (SI units), got {noise_sd}")
    n = int(round(duration / dt))
    if n < 2:
        raise ForwardError(f"duration {duration} s at dt {dt} s gives fewer than 2 samples")
    times = np.arange(n) * dt
    p = {**params, "w0": tip_deflection}
    y = simulate_signal(beam, model, p, times, n_elements=n_elements)
    rng = np.random.default_rng(seed)
    y = y + noise_sd * rng.standard_normal(n)
    truth = {
        "generator": "bayesbeam.trials.synthetic",
        "model": parse_model(model).name,
        "params": {k: float(v) for k, v in params.items()},
        "noise_sd": float(noise_sd),
        "n_elements": int(n_elements),
    }
    if seed is not None:  # TOML has no null
        truth["seed"] = int(seed)
    trial = Trial(
        times=times,
        values=y,
        quantity=beam.quantity,
        beam=beam,
        name=name,
        source={**truth, "seed": seed},
        initial={"tip_deflection": float(tip_deflection)},
        # write_trial keeps [meta] but not `source`: the true parameters must survive the
        # round trip through the file (recovery studies compare fits against them).
        meta={"synthetic": truth},
    )
    if out is not None:
        write_trial(trial, out)
    return trial
