"""bayesbeam: Bayesian uncertainty quantification of damping in cantilever beams.

Data flow: :class:`~bayesbeam.beam.Beam` → FE matrices (:mod:`bayesbeam.fem`) →
response (:mod:`bayesbeam.forward`) → likelihood → posterior (:mod:`bayesbeam.fit`) →
comparison (:mod:`bayesbeam.compare`) / diagnosis (:mod:`bayesbeam.diagnose`) → report.
All quantities are SI inside the package.
"""

from importlib.metadata import PackageNotFoundError, version

from bayesbeam.beam import Beam, Gradient, Segment
from bayesbeam.models import Model, parse_model

try:
    __version__ = version("bayesbeam")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

__all__ = ["Beam", "Gradient", "Model", "Segment", "__version__", "parse_model"]
