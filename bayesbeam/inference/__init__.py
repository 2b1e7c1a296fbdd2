"""One model on one trial: log posterior, MAP, emcee posterior, result record.

One model on one trial: the log posterior (:class:`Problem`), MAP and emcee
posterior (``bayesbeam.inference.fit.fit``), and the :class:`FitResult` record.

Layer: above :mod:`bayesbeam.trials`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "BETA1": ".problem",
    "clip_to_prior": ".fit",
    "decay_rate": ".fit",
    "default_priors": ".problem",
    "find_map": ".fit",
    "first_frequency": ".problem",
    "FIT_SETTINGS": ".fit",
    "fit_settings": ".fit",
    "FitError": ".fit",
    "FitResult": ".results",
    "laplace_covariance": ".fit",
    "make_provenance": ".results",
    "Problem": ".problem",
    "profile_linear": ".fit",
    "reference_modulus": ".problem",
    "ResultError": ".results",
    "SamplerCoordinates": ".fit",
    "scan_E": ".fit",
    "thin_result": ".fit",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
