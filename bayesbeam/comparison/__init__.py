"""Several models on one trial: evidences, criteria, verdicts, prior sensitivity.

Several models on one trial: evidences, criteria, verdicts and prior sensitivity
(``bayesbeam.comparison.compare.compare``).

Layer: above :mod:`bayesbeam.inference`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "compare_scores": ".compare",
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
