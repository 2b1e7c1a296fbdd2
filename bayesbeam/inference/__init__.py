"""One model on one trial: log posterior, MAP, emcee posterior, result record.

One model on one trial: the log posterior (:class:`Problem`), MAP and emcee
posterior (``bayesbeam.inference.fit.fit``; the MAP search in
:mod:`~bayesbeam.inference.optimum`, the sampler's coordinates in
:mod:`~bayesbeam.inference.coordinates`), its settings and their defaults
(:class:`FitSettings`), the :class:`FitResult` record, and posterior-predictive draws
(:func:`posterior_predictive`); one model on several trials with shared and pooled
parameters (:class:`JointProblem`, ``fit_joint``).

Layer: above :mod:`bayesbeam.trials`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "assess": ".adequacy",
    "BETA1": ".problem",
    "converge_mesh": ".mesh",
    "clip_to_prior": ".fit",
    "default_priors": ".problem",
    "DIAGNOSIS_DEFAULTS": ".settings",
    "find_map": ".fit",
    "first_frequency": ".problem",
    "FIT_DEFAULTS": ".settings",
    "fit_settings": ".settings",
    "FitError": ".fit",
    "FitResult": ".results",
    "FitSettings": ".settings",
    "fit_joint": ".joint_fit",
    "JointError": ".joint",
    "JointFit": ".joint_fit",
    "JointProblem": ".joint",
    "PoolCoordinates": ".joint",
    "diagonal_sd": ".optimum",
    "laplace_covariance": ".fit",
    "walker_scale": ".fit",
    "local_map": ".optimum",
    "map_bounds": ".optimum",
    "mesh_check": ".mesh",
    "newton_polish": ".optimum",
    "escape_bounds": ".optimum",
    "ParallelLogProb": ".parallel",
    "make_provenance": ".results",
    "posterior_predictive": ".predictive",
    "predictive_draws": ".predictive",
    "PredictiveError": ".predictive",
    "Problem": ".problem",
    "profile_linear": ".fit",
    "reference_modulus": ".problem",
    "ResultError": ".result_files",
    "SamplerCoordinates": ".coordinates",
    "sample_in_coordinates": ".coordinates",
    "scan_E": ".fit",
    "walker_count": ".settings",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
