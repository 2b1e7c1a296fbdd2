"""Prior distribution families of one parameter and their unconstrained sampling space.

Samplers and optimisers work on a vector ``u`` (design.md, "Sampling space"). Each
:class:`Prior` maps a physical value ``x`` to ``u`` and back and gives the density of
``u`` *including the Jacobian* ``|dx/du|``, normalised over u::

    log p(u) = log p_x(x(u)) + log |dx/du|,      ∫ p(u) du = 1.

With ``log_prob(u) = log_prior_u(u) + log_lik(theta(u))`` the integral
``∫ exp(log_prob) du`` is therefore the model evidence, whatever transform is used.

Families and their transforms
-----------------------------
=================  ===================  ============================================
family             ``u``                density of ``u``
=================  ===================  ============================================
``LogUniform``     ``log x``            uniform on ``[log lo, log hi]``
``Uniform``        ``x`` (default) or   uniform on ``[lo, hi]``, or the standard
                   ``logit`` of the     logistic density (``transform="logit"``,
                   position in range    unbounded ``u``)
``Normal``         ``x``                normal ``(mu, sd)``
``LogNormal``      ``log x``            normal ``(log median, sigma)``
``HalfNormal``     ``log x``            ``2 N(e^u; 0, s) e^u`` (half-normal in x)
=================  ===================  ============================================

Positive quantities (moduli, damping coefficients, noise scales) are sampled in log
space: their posteriors are closer to Gaussian there and one step size fits all
scales. ``LogUniform`` and identity ``Uniform`` leave ``u`` bounded; outside the
bounds :meth:`Prior.log_pdf_u` is ``-inf``, which an ensemble sampler handles by
rejecting the move. :meth:`Prior.from_u` clips ``u`` to the support first so that
a forward model is never handed an impossible value (a zero modulus, say) even for
a rejected proposal.

Priors are immutable; :meth:`Prior.scaled` returns a widened or narrowed copy for
prior-sensitivity studies of evidences, and :meth:`Prior.to_dict` /
:func:`prior_from_dict` round-trip through TOML and JSON (the ordered sets of named
priors and their TOML files are in :mod:`bayesbeam.stats.priors`, which re-exports all of
this module), e.g.::

    [priors.E]
    dist = "loguniform"
    lo = 1e9
    hi = 1e12
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, fields
from typing import Any, ClassVar

import numpy as np
from scipy import special

__all__ = [
    "HalfNormal",
    "LogNormal",
    "LogUniform",
    "Normal",
    "Prior",
    "PriorError",
    "Uniform",
    "prior_from_dict",
]

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
# exp() arguments are clipped to this range: exp(709) is the largest finite double,
# exp(-745) the smallest subnormal; beyond it exp would overflow (and warn).
_EXP_LO, _EXP_HI = -745.0, 709.0


class PriorError(ValueError):
    """A prior specification is invalid; the message says what and how to fix it."""


def _number(owner: str, name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise PriorError(f"{owner}: {name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise PriorError(f"{owner}: {name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise PriorError(f"{owner}: {name} must be finite, got {value!r}")
    return v


def _positive(owner: str, name: str, value: Any) -> float:
    v = _number(owner, name, value)
    if v <= 0:
        raise PriorError(f"{owner}: {name} must be positive, got {value!r}")
    return v


def _check_factor(factor: Any) -> float:
    try:
        f = float(factor)
    except (TypeError, ValueError):
        raise PriorError(f"scale factor must be a positive number, got {factor!r}") from None
    if not (math.isfinite(f) and f > 0):
        raise PriorError(f"scale factor must be a finite positive number, got {factor!r}")
    return f


def _exp(u: np.ndarray) -> np.ndarray:
    return np.exp(np.clip(u, _EXP_LO, _EXP_HI))


@dataclass(frozen=True)
class Prior(ABC):
    """Base class: one-dimensional prior with a transform to the sampling space ``u``.

    Subclasses are frozen dataclasses whose fields are the distribution's
    parameters (physical units of the parameter they describe).
    """

    dist: ClassVar[str] = ""
    # Validation of the fields, run by __post_init__ in this order:
    # name -> check(family, name, value), which returns the value as a float or raises.
    _checks: ClassVar[dict[str, Callable[[str, str, Any], float]]] = {}

    def __post_init__(self) -> None:
        for name, check in self._checks.items():
            value = check(type(self).__name__, name, getattr(self, name))
            object.__setattr__(self, name, value)

    # -- transform -----------------------------------------------------------------
    @abstractmethod
    def to_u(self, x: Any) -> np.ndarray:
        """Map physical values to the sampling space.

        Parameters
        ----------
        x : array_like
            Physical values (units of the parameter), any shape.

        Returns
        -------
        numpy.ndarray
            ``u``, same shape as ``x``.

        Raises
        ------
        PriorError
            Where the transform is undefined (e.g. ``x <= 0`` for a log transform).
        """

    @abstractmethod
    def from_u(self, u: Any) -> np.ndarray:
        """Map sampling-space values to physical values.

        Parameters
        ----------
        u : array_like
            Sampling-space values, any shape. Values outside :attr:`bounds_u` are
            clipped to it first (their prior density is zero anyway).

        Returns
        -------
        numpy.ndarray
            Physical values, same shape as ``u``.
        """

    @abstractmethod
    def log_pdf_u(self, u: Any) -> np.ndarray:
        """Log density of ``u``, Jacobian included, normalised over ``u``.

        Parameters
        ----------
        u : array_like
            Sampling-space values, any shape.

        Returns
        -------
        numpy.ndarray
            ``log p(u)``, same shape; ``-inf`` outside the support.
        """

    @abstractmethod
    def ppf_u(self, q: Any) -> np.ndarray:
        """Quantile function in the sampling space (prior transform of nested sampling).

        Parameters
        ----------
        q : array_like
            Probabilities in ``[0, 1]``, any shape.

        Returns
        -------
        numpy.ndarray
            ``u`` whose prior CDF is ``q``, same shape.
        """

    @property
    @abstractmethod
    def bounds(self) -> tuple[float, float]:
        """Support of the physical value ``(lo, hi)``; infinite where unbounded."""

    @property
    @abstractmethod
    def bounds_u(self) -> tuple[float, float]:
        """Support of ``u`` ``(lo, hi)``; infinite where unbounded."""

    @abstractmethod
    def scaled(self, factor: float) -> Prior:
        """Return a copy whose width is multiplied by ``factor`` about its centre.

        Log-space priors scale their width in ``log x`` (about the geometric centre
        or median), linear ones in ``x``; the families' docstrings say which width.

        Parameters
        ----------
        factor : float
            Positive width multiplier (``0.5`` halves, ``2`` doubles).

        Returns
        -------
        Prior
            A new prior of the same family.
        """

    # -- shared helpers ------------------------------------------------------------
    def log_pdf(self, x: Any) -> np.ndarray:
        """Log density of the physical value (per unit of the parameter).

        Parameters
        ----------
        x : array_like
            Physical values, any shape.

        Returns
        -------
        numpy.ndarray
            ``log p_x(x)``, same shape; ``-inf`` outside :attr:`bounds`.
        """
        x = np.asarray(x, dtype=float)
        lo, hi = self.bounds
        inside = (x >= lo) & (x <= hi) & np.isfinite(x)
        if self._log_transform:
            inside &= x > 0
        xs = np.where(inside, x, self._inside_point())
        u = self.to_u(xs)
        # p_x(x) = p_u(u) |du/dx|; du/dx = 1/x for log transforms.
        out = self.log_pdf_u(u) - self._log_dxdu(u, xs)
        return np.where(inside, out, -np.inf)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None):
        """Draw physical values from the prior: :meth:`sample_u` mapped by :meth:`from_u`.

        Parameters
        ----------
        rng, size
            As for :meth:`sample_u`.

        Returns
        -------
        numpy.ndarray or float
            Physical values of shape ``size``.
        """
        return self.from_u(self.sample_u(rng, size))

    def sample_u(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None):
        """Draw sampling-space values from the prior (inverse-CDF method).

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of randomness.
        size : int or tuple of int, optional
            Output shape; ``None`` gives a scalar.

        Returns
        -------
        numpy.ndarray or float
            ``u`` of shape ``size``.
        """
        return self.ppf_u(rng.random(size))

    def to_dict(self) -> dict[str, Any]:
        """Return a plain dict ``{"dist": ..., <parameters>}`` for TOML/JSON.

        Returns
        -------
        dict
            Inverse of :func:`prior_from_dict`.
        """
        out: dict[str, Any] = {"dist": self.dist}
        for f in fields(self):
            out[f.name] = getattr(self, f.name)
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Prior:
        """Build a prior from :meth:`to_dict` output; see :func:`prior_from_dict`.

        Parameters
        ----------
        d : mapping
            ``{"dist": name, <parameters>}``.

        Returns
        -------
        Prior
        """
        return prior_from_dict(d)

    # Subclass hooks for log_pdf.
    _log_transform: ClassVar[bool] = False

    def _log_dxdu(self, u: np.ndarray, x: np.ndarray) -> np.ndarray:
        if self._log_transform:
            return u  # x = e^u: log|dx/du| = u
        return np.zeros_like(u)

    def _inside_point(self) -> float:
        return float(self.from_u(self.ppf_u(0.5)))


def _check_range(prior: Prior) -> None:
    """Raise unless ``prior.lo < prior.hi`` (after the fields' own checks)."""
    if not prior.lo < prior.hi:
        raise PriorError(
            f"{type(prior).__name__}: need lo < hi, got lo={prior.lo!r}, hi={prior.hi!r}"
        )


def _bounded_log_pdf(u: Any, lo: float, hi: float, log_density: float) -> np.ndarray:
    u = np.asarray(u, dtype=float)
    return np.where((u >= lo) & (u <= hi), log_density, -np.inf)


@dataclass(frozen=True)
class _LogSpacePrior(Prior):
    """Prior on a positive value sampled in ``u = log x`` (default support: all x > 0).

    Families with a narrower support override :attr:`bounds`, :attr:`bounds_u` and
    :meth:`from_u`.
    """

    _log_transform: ClassVar[bool] = True

    @property
    def bounds(self) -> tuple[float, float]:  # noqa: D102 - documented on Prior
        return (0.0, math.inf)

    @property
    def bounds_u(self) -> tuple[float, float]:  # noqa: D102
        return (-math.inf, math.inf)

    def to_u(self, x: Any) -> np.ndarray:  # noqa: D102
        x = np.asarray(x, dtype=float)
        if np.any(~(x > 0)):
            raise PriorError(
                f"{type(self).__name__} is sampled in log space: values must be positive "
                f"to map to u, got min {np.nanmin(x) if x.size else x!r}"
            )
        return np.log(x)

    def from_u(self, u: Any) -> np.ndarray:  # noqa: D102
        return _exp(np.asarray(u, dtype=float))


@dataclass(frozen=True)
class LogUniform(_LogSpacePrior):
    """Log-uniform (reciprocal) prior on ``[lo, hi]``, ``0 < lo < hi``; ``u = log x``.

    Density ``p(x) = 1 / (x log(hi/lo))``; ``u`` is uniform on ``[log lo, log hi]``.
    :meth:`scaled` multiplies the width ``log(hi/lo)`` about the geometric centre
    ``sqrt(lo hi)``.
    """

    lo: float
    hi: float
    dist: ClassVar[str] = "loguniform"
    _checks: ClassVar = {"lo": _positive, "hi": _positive}

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_range(self)

    @property
    def bounds(self) -> tuple[float, float]:  # noqa: D102 - documented on Prior
        return (self.lo, self.hi)

    @property
    def bounds_u(self) -> tuple[float, float]:  # noqa: D102
        return (math.log(self.lo), math.log(self.hi))

    def from_u(self, u: Any) -> np.ndarray:  # noqa: D102
        lo, hi = self.bounds_u
        # exp(log lo) may differ from lo in the last bit: clip in x as well.
        return np.clip(np.exp(np.clip(np.asarray(u, dtype=float), lo, hi)), self.lo, self.hi)

    def log_pdf_u(self, u: Any) -> np.ndarray:  # noqa: D102
        lo, hi = self.bounds_u
        return _bounded_log_pdf(u, lo, hi, -math.log(hi - lo))

    def ppf_u(self, q: Any) -> np.ndarray:  # noqa: D102
        lo, hi = self.bounds_u
        return lo + np.asarray(q, dtype=float) * (hi - lo)

    def scaled(self, factor: float) -> LogUniform:  # noqa: D102
        f = _check_factor(factor)
        lo, hi = self.bounds_u
        c, w = 0.5 * (lo + hi), 0.5 * (hi - lo) * f
        return LogUniform(math.exp(c - w), math.exp(c + w))


@dataclass(frozen=True)
class Uniform(Prior):
    """Uniform prior on ``[lo, hi]``.

    ``transform="identity"`` (default) samples ``u = x`` inside the bounds (density
    ``1/(hi-lo)``, ``-inf`` outside): the posterior keeps its shape in ``u``.
    ``transform="logit"`` samples ``u = logit((x-lo)/(hi-lo))``, which is unbounded
    and has the standard logistic density; use it for optimisers that cannot take
    bounds. Both give the same evidence. :meth:`scaled` multiplies ``hi - lo``
    about the midpoint (the caller must keep physical limits, e.g. ``|rho| < 1``).
    """

    lo: float
    hi: float
    transform: str = "identity"
    dist: ClassVar[str] = "uniform"
    _checks: ClassVar = {"lo": _number, "hi": _number}

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_range(self)
        if self.transform not in ("identity", "logit"):
            raise PriorError(
                f"Uniform: transform must be 'identity' or 'logit', got {self.transform!r}"
            )

    @property
    def _logit(self) -> bool:
        return self.transform == "logit"

    @property
    def bounds(self) -> tuple[float, float]:  # noqa: D102
        return (self.lo, self.hi)

    @property
    def bounds_u(self) -> tuple[float, float]:  # noqa: D102
        return (-math.inf, math.inf) if self._logit else (self.lo, self.hi)

    def to_u(self, x: Any) -> np.ndarray:  # noqa: D102
        x = np.asarray(x, dtype=float)
        if not self._logit:
            return x.copy()
        if np.any(~((x >= self.lo) & (x <= self.hi))):
            raise PriorError(
                f"Uniform(logit): values must lie in [{self.lo}, {self.hi}] to map to u"
            )
        return special.logit((x - self.lo) / (self.hi - self.lo))

    def from_u(self, u: Any) -> np.ndarray:  # noqa: D102
        u = np.asarray(u, dtype=float)
        if self._logit:
            x = self.lo + (self.hi - self.lo) * special.expit(u)
        else:
            x = u
        return np.clip(x, self.lo, self.hi)

    def log_pdf_u(self, u: Any) -> np.ndarray:  # noqa: D102
        u = np.asarray(u, dtype=float)
        if self._logit:
            # standard logistic density: log σ(u) + log σ(-u), written stably.
            return -np.logaddexp(0.0, u) - np.logaddexp(0.0, -u)
        return _bounded_log_pdf(u, self.lo, self.hi, -math.log(self.hi - self.lo))

    def ppf_u(self, q: Any) -> np.ndarray:  # noqa: D102
        q = np.asarray(q, dtype=float)
        if self._logit:
            return special.logit(q)
        return self.lo + q * (self.hi - self.lo)

    def log_pdf(self, x: Any) -> np.ndarray:  # noqa: D102 - documented on Prior
        # Direct form: the generic u-route would give -inf - (-inf) at the logit edges.
        x = np.asarray(x, dtype=float)
        inside = (x >= self.lo) & (x <= self.hi)
        return np.where(inside, -math.log(self.hi - self.lo), -np.inf)

    def scaled(self, factor: float) -> Uniform:  # noqa: D102
        f = _check_factor(factor)
        c, w = 0.5 * (self.lo + self.hi), 0.5 * (self.hi - self.lo) * f
        return Uniform(c - w, c + w, self.transform)

    def to_dict(self) -> dict[str, Any]:  # noqa: D102
        d = super().to_dict()
        if self.transform == "identity":
            del d["transform"]  # keep the common case short in TOML files
        return d


@dataclass(frozen=True)
class Normal(Prior):
    """Normal prior ``N(mu, sd)`` on an unbounded parameter; ``u = x``.

    :meth:`scaled` multiplies ``sd``.
    """

    mu: float
    sd: float
    dist: ClassVar[str] = "normal"
    _checks: ClassVar = {"mu": _number, "sd": _positive}

    @property
    def bounds(self) -> tuple[float, float]:  # noqa: D102
        return (-math.inf, math.inf)

    @property
    def bounds_u(self) -> tuple[float, float]:  # noqa: D102
        return (-math.inf, math.inf)

    def to_u(self, x: Any) -> np.ndarray:  # noqa: D102
        return np.array(x, dtype=float)

    def from_u(self, u: Any) -> np.ndarray:  # noqa: D102
        return np.array(u, dtype=float)

    def log_pdf_u(self, u: Any) -> np.ndarray:  # noqa: D102
        z = (np.asarray(u, dtype=float) - self.mu) / self.sd
        with np.errstate(over="ignore"):  # |z| > 1e154: density 0, log -inf (exact)
            return -0.5 * z * z - math.log(self.sd) - _LOG_SQRT_2PI

    def ppf_u(self, q: Any) -> np.ndarray:  # noqa: D102
        return self.mu + self.sd * special.ndtri(np.asarray(q, dtype=float))

    def scaled(self, factor: float) -> Normal:  # noqa: D102
        return Normal(self.mu, self.sd * _check_factor(factor))


@dataclass(frozen=True)
class LogNormal(_LogSpacePrior):
    """Log-normal prior: ``log x ~ N(log median, sigma)``; ``u = log x``.

    ``median`` is in the parameter's units, ``sigma`` is dimensionless (natural-log
    standard deviation). :meth:`scaled` multiplies ``sigma``.
    """

    median: float
    sigma: float
    dist: ClassVar[str] = "lognormal"
    _checks: ClassVar = {"median": _positive, "sigma": _positive}

    def log_pdf_u(self, u: Any) -> np.ndarray:  # noqa: D102
        z = (np.asarray(u, dtype=float) - math.log(self.median)) / self.sigma
        return -0.5 * z * z - math.log(self.sigma) - _LOG_SQRT_2PI

    def ppf_u(self, q: Any) -> np.ndarray:  # noqa: D102
        return math.log(self.median) + self.sigma * special.ndtri(np.asarray(q, dtype=float))

    def scaled(self, factor: float) -> LogNormal:  # noqa: D102
        return LogNormal(self.median, self.sigma * _check_factor(factor))


@dataclass(frozen=True)
class HalfNormal(_LogSpacePrior):
    """Half-normal prior on ``x > 0`` with scale ``scale``; ``u = log x``.

    ``p(x) = 2 N(x; 0, scale)`` for ``x > 0``; in ``u``:
    ``p(u) = 2 N(e^u; 0, scale) e^u``. Weakly informative for noise scales.
    :meth:`scaled` multiplies ``scale``.
    """

    scale: float
    dist: ClassVar[str] = "halfnormal"
    _checks: ClassVar = {"scale": _positive}

    def log_pdf_u(self, u: Any) -> np.ndarray:  # noqa: D102
        u = np.asarray(u, dtype=float)
        # z = x/scale; clip the exponent so z*z cannot overflow (z = e^300 already
        # gives log p ~ -1e260, i.e. numerically zero density).
        z = np.exp(np.clip(u - math.log(self.scale), _EXP_LO, 300.0))
        return math.log(2.0) - _LOG_SQRT_2PI - math.log(self.scale) - 0.5 * z * z + u

    def ppf_u(self, q: Any) -> np.ndarray:  # noqa: D102
        q = np.asarray(q, dtype=float)
        with np.errstate(divide="ignore"):  # q = 0 maps to x = 0, u = -inf exactly
            return np.log(self.scale * special.ndtri(0.5 * (1.0 + q)))

    def scaled(self, factor: float) -> HalfNormal:  # noqa: D102
        return HalfNormal(self.scale * _check_factor(factor))


_FAMILIES: dict[str, type[Prior]] = {
    cls.dist: cls for cls in (LogUniform, Uniform, Normal, LogNormal, HalfNormal)
}


def prior_from_dict(d: Mapping[str, Any]) -> Prior:
    """Build a prior from ``{"dist": name, <parameters>}`` (a TOML table or JSON object).

    Parameters
    ----------
    d : mapping
        ``dist`` is one of ``loguniform`` (``lo``, ``hi``), ``uniform`` (``lo``,
        ``hi``, optional ``transform``), ``normal`` (``mu``, ``sd``), ``lognormal``
        (``median``, ``sigma``), ``halfnormal`` (``scale``); case-insensitive.

    Returns
    -------
    Prior

    Raises
    ------
    PriorError
        For an unknown family, missing or unexpected keys, or invalid values.
    """
    if isinstance(d, Prior):
        return d
    if not isinstance(d, Mapping):
        raise PriorError(f"a prior must be a table/dict with a 'dist' key, got {d!r}")
    params = dict(d)
    dist = params.pop("dist", None)
    if not isinstance(dist, str):
        raise PriorError(f"prior {d!r} needs a 'dist' key, one of {sorted(_FAMILIES)}")
    cls = _FAMILIES.get(dist.strip().lower().replace("-", "").replace("_", ""))
    if cls is None:
        raise PriorError(f"unknown prior dist {dist!r}; choose one of {sorted(_FAMILIES)}")
    names = [f.name for f in fields(cls)]
    required = [f.name for f in fields(cls) if f.default is MISSING]
    unknown = sorted(set(params) - set(names))
    missing = [n for n in required if n not in params]
    if unknown or missing:
        raise PriorError(
            f"{cls.dist} prior takes keys {names}"
            + (f"; unexpected {unknown}" if unknown else "")
            + (f"; missing {missing}" if missing else "")
        )
    return cls(**params)
