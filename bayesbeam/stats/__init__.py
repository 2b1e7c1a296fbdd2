"""Statistics that know nothing of beams.

Statistics that know nothing of beams: prior families and prior sets, Gaussian
likelihoods (i.i.d., AR(1)), emcee sampling with convergence checks and checkpoints,
bridge-sampling / Laplace evidence, information criteria, evidence ranking,
finite-difference derivatives, and whiteness tests of residual series.

Layer: imports only :mod:`bayesbeam._util` (independent of :mod:`bayesbeam.physics`).
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "aic": ".criteria",
    "ar1_loglik": ".likelihood",
    "ar1_pointwise": ".likelihood",
    "autocorr_time": ".convergence",
    "autocorrelation": ".whiteness",
    "bic": ".criteria",
    "bridge_sampling": ".evidence",
    "burn_in": ".convergence",
    "Chain": ".sampling",
    "Check": ".convergence",
    "check_convergence": ".convergence",
    "CheckpointBackend": ".checkpoint",
    "CriteriaError": ".criteria",
    "DEFAULT_THRESHOLD": ".ranking",
    "de_moves": ".sampling",
    "effective_sample_size": ".evidence",
    "elpd_difference": ".criteria",
    "ess_rhat": ".convergence",
    "Evidence": ".evidence",
    "EvidenceError": ".evidence",
    "EvidenceWarning": ".evidence",
    "failed_criteria": ".convergence",
    "fd_gradient": ".numdiff",
    "fd_hessian": ".numdiff",
    "fisher_g": ".whiteness",
    "group_loglik": ".criteria",
    "HalfNormal": ".families",
    "HessianNotNegativeDefiniteError": ".evidence",
    "iid_loglik": ".likelihood",
    "iid_pointwise": ".likelihood",
    "init_walkers": ".sampling",
    "laplace_evidence": ".evidence",
    "LikelihoodError": ".likelihood",
    "ljung_box": ".whiteness",
    "LogNormal": ".families",
    "logo": ".criteria",
    "LogUniform": ".families",
    "LOO": ".criteria",
    "loo": ".criteria",
    "make_log_prob": ".sampling",
    "Normal": ".families",
    "NotConvergedWarning": ".sampling",
    "open_checkpoint": ".checkpoint",
    "ParetoKWarning": ".criteria",
    "Prior": ".families",
    "prior_from_dict": ".families",
    "PriorError": ".families",
    "PriorSet": ".priors",
    "read_meta": ".checkpoint",
    "saved_steps": ".checkpoint",
    "preburn_walkers": ".sampling",
    "run_emcee": ".sampling",
    "SamplingError": ".checkpoint",
    "stationary_ar1": ".likelihood",
    "STRANDED_NATS": ".sampling",
    "standardized_innovations": ".likelihood",
    "Uniform": ".families",
    "WAIC": ".criteria",
    "waic": ".criteria",
    "WAICWarning": ".criteria",
    "WhitenessError": ".whiteness",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
