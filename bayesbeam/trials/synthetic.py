"""Synthetic trials from the package's own forward model (for tests, studies and users)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward, ForwardError
from bayesbeam.physics.models import parse_model
from bayesbeam.trials.io import write_trial
from bayesbeam.trials.trial import BANDWIDTH_PER_RATE, Trial

__all__ = ["MAX_SIMULATED_SAMPLES", "simulate_sensor", "simulate_signal", "simulate_trial"]

#: Most samples :func:`simulate_trial` makes (duration / dt). While simulated and written
#: a sample costs about :data:`_BYTES_PER_SAMPLE` bytes of memory (times, signal, noise,
#: the propagator's rows, the CSV's columns; measured: +62 MB and 7 s for 1e6 samples)
#: and 26 bytes of CSV: 10 million samples take about 0.6 GB, 0.3 GB on disk and a
#: minute, far more than any fit uses (its default budget is 16384 samples).
MAX_SIMULATED_SAMPLES = 10_000_000
_BYTES_PER_SAMPLE = 64


def simulate_signal(
    beam: Beam,
    model: str,
    params: dict[str, float],
    times: np.ndarray,
    *,
    n_elements: int = 16,
    initial: str = "release",
    bandwidth: float | None = None,
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
    bandwidth : float, optional
        Sensor bandwidth in Hz (ideal anti-alias filter, see
        :class:`~bayesbeam.physics.forward.Forward`); None: the default of a trial with
        these stamps (median sampling rate / 2.56,
        :attr:`~bayesbeam.trials.trial.Trial.sensor_band`); ``inf``: every mode.

    Returns
    -------
    ndarray, shape (T,)
        Signal in SI units of ``beam.quantity``.
    """
    if bandwidth is None and np.size(times) >= 2:
        bandwidth = BANDWIDTH_PER_RATE / float(np.median(np.diff(np.asarray(times, float))))
    if parse_model(model).nonlinear:
        from bayesbeam.physics.nonlinear import NonlinearForward

        fwd = NonlinearForward(beam, model, times, n_elements=n_elements, initial=initial,
                               bandwidth=bandwidth)
    else:
        fwd = Forward(beam, model, times, n_elements=n_elements, initial=initial,
                      bandwidth=bandwidth)
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
    bandwidth: float | None = None,
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
        Record length and sample interval in s; at most :data:`MAX_SIMULATED_SAMPLES`
        samples (``duration / dt``).
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
    bandwidth : float, optional
        Sensor bandwidth in Hz, stored in the trial; None: the trial default
        (:attr:`~bayesbeam.trials.trial.Trial.sensor_band`, sampling rate / 2.56). The
        signal is what a sensor with that band records (``inf``: no filter).

    Returns
    -------
    Trial
        Its ``meta["synthetic"]`` (written to the file's ``[meta.synthetic]`` table) records
        the generator: model, true ``params`` (SI), ``noise_sd``, ``n_elements`` and ``seed``.

    Raises
    ------
    ForwardError
        For a non-positive or non-finite duration or dt, a negative noise sd, a
        non-finite tip deflection, more than :data:`MAX_SIMULATED_SAMPLES` samples
        (before anything is allocated) or parameters the model does not take.
    """
    if not isinstance(beam, Beam):
        beam = Beam.from_toml(beam)
    for label, v in (("duration", duration), ("dt", dt)):
        if not (np.isfinite(v) and v > 0):
            raise ForwardError(f"{label} must be a positive number of seconds, got {v}")
    if not (np.isfinite(noise_sd) and noise_sd >= 0):
        raise ForwardError(f"noise_sd must be a finite number >= 0 (SI units), got {noise_sd}")
    if not np.isfinite(tip_deflection):
        raise ForwardError(f"tip_deflection must be a finite number of metres, got "
                           f"{tip_deflection}")
    if duration / dt > MAX_SIMULATED_SAMPLES:  # checked before anything is allocated
        n_asked = duration / dt
        gb = n_asked * _BYTES_PER_SAMPLE / 1e9
        raise ForwardError(
            f"duration {duration:g} s at dt {dt:g} s is {n_asked:.3g} samples (about "
            f"{gb:,.0f} GB of memory), above the limit of "
            f"{MAX_SIMULATED_SAMPLES:,} ({MAX_SIMULATED_SAMPLES * dt:.4g} s at this dt): "
            "give a shorter duration (--duration) or a larger sample step (--dt)"
        )
    n = int(round(duration / dt))
    if n < 2:
        raise ForwardError(f"duration {duration} s at dt {dt} s gives fewer than 2 samples")
    times = np.arange(n) * dt
    p = {**params, "w0": tip_deflection}
    y = simulate_signal(beam, model, p, times, n_elements=n_elements, bandwidth=bandwidth)
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
        bandwidth=bandwidth,
    )
    if out is not None:
        write_trial(trial, out)
    return trial


def simulate_sensor(
    beam: Beam,
    model: str,
    params: dict[str, float],
    times: np.ndarray,
    *,
    t0: float = 0.0,
    bandwidth: float | None = None,
    n_elements: int = 64,
    oversample: int = 16,
    initial: str = "release",
) -> np.ndarray:
    """Noise-free signal as a real sensor records it: fine mesh, every mode, FIR anti-alias.

    An independent route to test data (no inverse crime against a fit's forward model):
    the beam is simulated on a fine mesh with *every* mode up to the fine grid's Nyquist
    frequency (no ideal band limit at the record's band) on a uniform grid
    ``oversample`` times faster than the record, passed through a
    zero-phase Kaiser-window FIR low-pass (pass band up to ``bandwidth``, stop band from
    the record's Nyquist frequency, 80 dB) as a delta-sigma converter's decimation filter
    would, and interpolated onto ``times`` (cubic spline of the filtered fine signal; its
    error is ``O((2π f h)^4)``, below 1e-7 of the signal in the pass band for
    ``oversample >= 16``).

    Parameters
    ----------
    beam : Beam
    model : str
        Linear model name, e.g. ``'viscous+kv'``.
    params : dict
        Physical and initial-condition parameters (SI), ``E`` defaulting to ``beam.E``.
    times : ndarray, shape (T,)
        Record stamps in s (non-uniform allowed), all at least one filter half-length
        after ``t0`` (the filter must have settled after the release: the error says how
        long that is).
    t0 : float
        Release (or impact) instant in s.
    bandwidth : float, optional
        Pass-band edge in Hz; default the sampling rate (inverse median step) / 2.56.
    n_elements : int
        Mesh of the generating model.
    oversample : int
        Rate of the fine grid over the record's rate.
    initial : str
        See :class:`bayesbeam.physics.forward.Forward`.

    Returns
    -------
    ndarray, shape (T,)
        Signal in SI units of ``beam.quantity``.
    """
    import scipy.interpolate
    import scipy.signal

    t = np.asarray(times, dtype=float)
    if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0):
        raise ForwardError("times must be a strictly increasing 1-D array (s)")
    fs = 1.0 / float(np.median(np.diff(t)))
    band = BANDWIDTH_PER_RATE * fs if bandwidth is None else float(bandwidth)
    if not 0 < band < fs / 2:
        raise ForwardError(f"bandwidth must lie in (0, {fs / 2:g}) Hz, got {band!r}")
    fs_fine = oversample * fs
    numtaps, beta = scipy.signal.kaiserord(80.0, (fs / 2 - band) / (fs_fine / 2))
    numtaps |= 1  # odd: a symmetric filter with an integer delay, removed below
    half = numtaps // 2
    settle = half / fs_fine
    if t[0] - t0 < settle:
        raise ForwardError(
            f"the first stamp ({t[0]:g} s) must come at least {settle:.4g} s after t0 = {t0:g} s "
            "(the anti-alias filter's half length); drop the earlier samples"
        )
    taps = scipy.signal.firwin(numtaps, 0.5 * (band + fs / 2), window=("kaiser", beta),
                               fs=fs_fine)
    n_fine = int(np.ceil((t[-1] - t0) * fs_fine)) + half + 2
    fine_t = t0 + np.arange(n_fine) / fs_fine
    # Eigen-solutions above the fine grid's Nyquist frequency would alias into the band
    # (an acceleration release holds every mesh mode with comparable weight, up to MHz
    # on a fine mesh, and viscous damping leaves them ringing); a real sensor's analogue
    # front end and oversampling converter remove them, and so does the ideal band here.
    y = simulate_signal(beam, model, params, fine_t, n_elements=n_elements, initial=initial,
                        bandwidth=fs_fine / 2)
    # Zero-phase: full convolution, then shift by the filter delay. Outputs before t0 +
    # settle would mix in the (unsimulated) pre-release signal and are never used.
    yf = scipy.signal.fftconvolve(y, taps)[half : half + n_fine]
    keep = slice(half, n_fine - half)
    spline = scipy.interpolate.CubicSpline(fine_t[keep], yf[keep])
    return spline(t)
