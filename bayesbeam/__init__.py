"""bayesbeam: Bayesian uncertainty quantification of damping in cantilever beams.

The package follows the data flow, one subpackage a stage (ARCHITECTURE.md has the map):
:mod:`~bayesbeam.physics` (beam → FE matrices → response) and :mod:`~bayesbeam.stats`
(priors, likelihood, sampling, evidence) → :mod:`~bayesbeam.trials` (records) →
:mod:`~bayesbeam.inference` (posterior) → :mod:`~bayesbeam.comparison` →
:mod:`~bayesbeam.diagnosis` → :mod:`~bayesbeam.report`, with :mod:`~bayesbeam.jobs`
(many fits, demo, benchmark) and :mod:`~bayesbeam.cli` at the edge. All quantities are SI.

The names below are what a notebook needs; they are imported on first use, so that
``import bayesbeam`` stays fast::

    import bayesbeam as bb

    trial = bb.read_trial("data/beam1-trial1.toml")
    result = bb.fit(trial, "viscous+kv", seed=1)
    print(bb.compare(trial, ["viscous", "viscous+kv", "viscous+sh"], seed=1))
"""

from bayesbeam._util import distribution_version, lazy_exports

__version__ = distribution_version("bayesbeam")

_EXPORTS = {
    # physics
    "Beam": "bayesbeam.physics.beam",
    "Gradient": "bayesbeam.physics.beam",
    "Segment": "bayesbeam.physics.beam",
    "Model": "bayesbeam.physics.models",
    "parse_model": "bayesbeam.physics.models",
    "Forward": "bayesbeam.physics.forward",
    # trials
    "Trial": "bayesbeam.trials.trial",
    "read_trial": "bayesbeam.trials.io",
    "write_trial": "bayesbeam.trials.io",
    "simulate_trial": "bayesbeam.trials.synthetic",
    "load_enes": "bayesbeam.trials.realdata",
    "load_hrshm": "bayesbeam.trials.realdata",
    # inference
    "Problem": "bayesbeam.inference.problem",
    "fit": "bayesbeam.inference.fit",
    "fit_joint": "bayesbeam.inference.joint_fit",
    "compare_joint": "bayesbeam.comparison.joint",
    "FitResult": "bayesbeam.inference.results",
    # comparison, diagnosis, report
    "compare": "bayesbeam.comparison.compare",
    "Comparison": "bayesbeam.comparison.compare",
    "diagnose": "bayesbeam.diagnosis.diagnose",
    "Diagnosis": "bayesbeam.diagnosis.records",
    "write_report": "bayesbeam.report.html",
}

__all__ = sorted([*_EXPORTS, "__version__"])
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
