"""Measured and simulated records.

Measured or simulated records: the :class:`Trial` record, trial files, public real-data
loaders, synthetic trials, modal identification from a record's samples, and the
record's noise floor from a model-free fit of damped sinusoids.

Layer: above :mod:`bayesbeam.physics` and :mod:`bayesbeam.stats`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "amplitude_curves": ".amplitude",
    "AmplitudeBin": ".amplitude_bins",
    "AmplitudeCurves": ".amplitude",
    "ResidualLine": ".residual_lines",
    "tip_factor": ".amplitude_bins",
    "band_modal_estimate": ".modal_id",
    "damped_sinusoids": ".modal_id",
    "decay_rate_vs_amplitude": ".modal_id",
    "envelope_decay_vs_amplitude": ".modal_id",
    "first_mode_decay_rate": ".modal_id",
    "DecayAmplitude": ".modal_id",
    "DEFAULT_ROOT": ".realdata",
    "ENES": ".realdata",
    "enes_beam": ".realdata",
    "FORMAT_VERSION": ".io",
    "HRSHM": ".realdata",
    "harmonic_text": ".harmonics",
    "hrshm_beam": ".realdata",
    "list_real_datasets": ".realdata",
    "load_enes": ".realdata",
    "load_hrshm": ".realdata",
    "ModalEstimate": ".modal_id",
    "noise_floor": ".noise",
    "NoiseFloor": ".noise",
    "NoiseFloorError": ".noise",
    "periodogram": ".modal_id",
    "check_trial": ".checks",
    "read_trial": ".io",
    "RealDataError": ".realdata",
    "RealRecord": ".realdata",
    "record_at": ".realdata",
    "resolve_root": ".realdata",
    "second_harmonic": ".harmonics",
    "SecondHarmonic": ".harmonics",
    "SignatureError": ".modal_id",
    "simulate_sensor": ".synthetic",
    "simulate_signal": ".synthetic",
    "simulate_trial": ".synthetic",
    "spectral_peak": ".modal_id",
    "STANDARD_GRAVITY": ".trial",
    "Trial": ".trial",
    "TrialError": ".trial",
    "uniform_grid": ".modal_id",
    "UNIFORM_RTOL": ".trial",
    "unit_factor": ".trial",
    "UNITS": ".trial",
    "write_trial": ".io",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
