"""Several models on one trial: evidences, criteria, verdicts, prior sensitivity.

Several models on one trial: evidences, criteria, verdicts and prior sensitivity
(``bayesbeam.comparison.compare.compare``); joint variants of one model on several
trials, which parameters they share (:func:`compare_joint`).

Layer: above :mod:`bayesbeam.inference`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "compare_joint": ".joint",
    "compare_scores": ".compare",
    "JointComparison": ".joint",
    "JointScore": ".joint",
    "score_joint": ".joint",
    "CompareError": ".scoring",
    "Comparison": ".compare",
    "evaluate": ".scoring",
    "ModelScore": ".scoring",
    "prior_reweight": ".sensitivity",
    "prior_sensitivity": ".sensitivity",
    "PriorReweight": ".sensitivity",
    "SensitivityRow": ".sensitivity",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
