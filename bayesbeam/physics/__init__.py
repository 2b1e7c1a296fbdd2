"""The beam and its response.

The beam and its response: description (SI), cubic-Hermite FE matrices, Banks–Inman
hysteresis operator, exact batched propagation, forward model, slow-flow nonlinear damping.

Layer: imports only :mod:`bayesbeam._util` (independent of :mod:`bayesbeam.stats`).
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "assemble": ".fem",
    "band_limit": ".sensor",
    "Beam": ".beam",
    "PointMass": ".beam",
    "Finding": ".plausible",
    "PLAUSIBLE": ".plausible",
    "plausibility": ".plausible",
    "BeamError": ".beam",
    "eigenvalues": ".propagate",
    "expm_batched": ".expm",
    "FEMError": ".fem",
    "FEModel": ".fem",
    "Forward": ".forward",
    "ForwardError": ".inputs",
    "Gradient": ".beam",
    "HysteresisError": ".hysteresis",
    "HysteresisOperator": ".hysteresis",
    "initial_names": ".inputs",
    "LAWS": ".models",
    "mesh_nodes": ".fem",
    "modal_properties": ".forward",
    "Model": ".models",
    "ModelError": ".models",
    "NOISE": ".models",
    "NONLINEAR": ".models",
    "nonlinear_damping_scales": ".nonlinear",
    "NonlinearError": ".nonlinear",
    "NonlinearForward": ".nonlinear",
    "numba_available": ".propagate",
    "parameter_columns": ".inputs",
    "parse_model": ".models",
    "PropagationError": ".expm",
    "QUANTITIES": ".beam",
    "Response": ".forward",
    "response_times": ".propagate",
    "response_uniform": ".propagate",
    "Segment": ".beam",
    "single_blas_thread": ".propagate",
    "state_matrix": ".propagate",
    "static_tip_shape": ".fem",
    "STRUCTURAL": ".models",
    "two_tone_drag": ".nonlinear",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
