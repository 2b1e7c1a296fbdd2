"""What the simulation gets wrong, the named cause and the gain.

What the simulation gets wrong: residual signatures, the catalogue search, and the
:class:`Diagnosis` record (``bayesbeam.diagnosis.diagnose.diagnose``).

Layer: above :mod:`bayesbeam.comparison`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "CandidateScore": ".records",
    "CATALOGUE": ".diagnose",
    "compute_signatures": ".signatures",
    "describe_signatures": ".records",
    "DiagnoseError": ".search",
    "Diagnosis": ".records",
    "ModeComparison": ".signatures",
    "model_modes": ".signatures",
    "plot_signatures": ".signatures",
    "Round": ".records",
    "SCREEN_THRESHOLD": ".diagnose",
    "signature_support": ".diagnose",
    "Signatures": ".signatures",
    "SIGNIFICANCE": ".diagnose",
    "TIE": ".diagnose",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
