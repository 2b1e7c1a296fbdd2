"""Ordered sets of named priors (:class:`PriorSet`) and their TOML/JSON form.

A :class:`PriorSet` maps parameter names, in the column order of a model's ``theta``
arrays, to one-parameter priors and provides the vectorised maps between the physical
values and the unconstrained sampling space ``u`` (density of ``u`` with the Jacobian
included, so that ``∫ exp(log_prior_u + log_lik) du`` is the evidence). The families
themselves (``LogUniform``, ``Uniform``, ``Normal``, ``LogNormal``, ``HalfNormal``) and
:func:`prior_from_dict` live in :mod:`bayesbeam.stats.families` and are re-exported here.
A TOML file overrides a model's default priors, e.g.::

    [priors.E]
    dist = "loguniform"
    lo = 1e9
    hi = 1e12
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import read_toml
from bayesbeam.stats.families import (
    Prior,
    PriorError,
    prior_from_dict,
)

__all__ = [
    "PriorSet",
]


class PriorSet(Mapping[str, Prior]):
    """Ordered, immutable mapping ``name -> Prior`` with vectorised helpers.

    The order of names is the order of the columns of every ``U`` / ``theta``
    array, so it must match the model's parameter order.

    Parameters
    ----------
    priors : mapping or iterable of (name, Prior or dict)
        Priors in parameter order; dict values go through :func:`prior_from_dict`.

    Raises
    ------
    PriorError
        On empty or duplicate names or invalid priors.
    """

    def __init__(self, priors: Mapping[str, Any] | Iterable[tuple[str, Any]]):
        items = list(priors.items()) if isinstance(priors, Mapping) else list(priors)
        seen: dict[str, Prior] = {}
        for item in items:
            try:
                name, prior = item
            except (TypeError, ValueError):
                raise PriorError(f"expected (name, prior) pairs, got {item!r}") from None
            if not isinstance(name, str) or not name:
                raise PriorError(f"parameter names must be non-empty strings, got {name!r}")
            if name in seen:
                raise PriorError(f"duplicate parameter name {name!r}")
            try:
                seen[name] = prior_from_dict(prior)
            except PriorError as exc:
                raise PriorError(f"prior for {name!r}: {exc}") from None
        if not seen:
            raise PriorError("a PriorSet needs at least one parameter")
        self._priors = seen
        self._names = tuple(seen)

    # -- Mapping protocol ----------------------------------------------------------
    def __getitem__(self, name: str) -> Prior:
        try:
            return self._priors[name]
        except KeyError:
            raise KeyError(f"no prior for {name!r}; parameters are {list(self._names)}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PriorSet):
            return NotImplemented
        return list(self._priors.items()) == list(other._priors.items())

    def __hash__(self) -> int:
        return hash(tuple(self._priors.items()))

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v!r}" for k, v in self._priors.items())
        return f"PriorSet({inner})"

    # -- shape helpers -------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names in column order."""
        return self._names

    @property
    def ndim(self) -> int:
        """Number of parameters."""
        return len(self._names)

    @property
    def bounds(self) -> np.ndarray:
        """Physical supports, shape ``(ndim, 2)`` (``±inf`` where unbounded)."""
        return np.array([p.bounds for p in self._priors.values()], dtype=float)

    @property
    def bounds_u(self) -> np.ndarray:
        """Sampling-space supports, shape ``(ndim, 2)`` (``±inf`` where unbounded)."""
        return np.array([p.bounds_u for p in self._priors.values()], dtype=float)

    def _cols(self, a: Any, what: str) -> np.ndarray:
        a = np.asarray(a, dtype=float)
        if a.ndim == 0 or a.shape[-1] != self.ndim:
            raise PriorError(
                f"{what} must have last axis of length {self.ndim} ({list(self._names)}), "
                f"got shape {a.shape}"
            )
        return a

    def _per_column(self, a: Any, what: str, method: str) -> np.ndarray:
        """Apply the one-parameter map ``method`` of each prior to its column of ``a``."""
        a = self._cols(a, what)
        out = np.empty_like(a)
        for j, (name, p) in enumerate(self._priors.items()):
            try:
                out[..., j] = getattr(p, method)(a[..., j])
            except PriorError as exc:
                raise PriorError(f"parameter {name!r}: {exc}") from None
        return out

    # -- vectorised maps -----------------------------------------------------------
    def log_prior_u(self, U: Any) -> np.ndarray:
        """Sum of the per-parameter log densities in ``u`` (Jacobians included).

        Parameters
        ----------
        U : array_like, shape (..., ndim)
            Sampling-space points.

        Returns
        -------
        numpy.ndarray, shape (...)
            ``log p(u)``; ``-inf`` outside the support.
        """
        U = self._cols(U, "U")
        out = np.zeros(U.shape[:-1])
        for j, p in enumerate(self._priors.values()):
            out = out + p.log_pdf_u(U[..., j])
        return out

    def log_posterior_u(self, U: Any, log_likelihood: Any) -> np.ndarray:
        """Unnormalised log posterior ``log_prior_u(U) + log_likelihood(U)``, shape (k,).

        The likelihood is evaluated only at points inside the prior's support; NaN
        becomes ``-inf`` (a density of zero, never a number that poisons a sampler).
        Its integral over ``u`` is the evidence.

        Parameters
        ----------
        U : array_like, shape (k, ndim)
        log_likelihood : callable
            ``(m, ndim) -> (m,)``, vectorised.

        Returns
        -------
        ndarray, shape (k,)
        """
        U = np.atleast_2d(np.asarray(U, dtype=float))
        lp = self.log_prior_u(U)
        out = np.full(U.shape[0], -np.inf)
        ok = np.isfinite(lp)
        if np.any(ok):
            out[ok] = lp[ok] + log_likelihood(U[ok])
        out[np.isnan(out)] = -np.inf
        return out

    def to_theta(self, U: Any) -> np.ndarray:
        """Map sampling-space points to physical parameter values.

        Each column goes through its prior's :meth:`~bayesbeam.stats.priors.Prior.from_u`, so
        points outside the support are clipped to it.

        Parameters
        ----------
        U : array_like, shape (..., ndim)
            Sampling-space points, columns in :attr:`names` order.

        Returns
        -------
        numpy.ndarray, shape (..., ndim)
            Physical values (SI units of each parameter).
        """
        return self._per_column(U, "U", "from_u")

    def to_u(self, theta: Any) -> np.ndarray:
        """Map physical parameter values to the sampling space.

        Parameters
        ----------
        theta : array_like, shape (..., ndim)
            Physical values, columns in :attr:`names` order.

        Returns
        -------
        numpy.ndarray, shape (..., ndim)
            ``u`` of every point.

        Raises
        ------
        PriorError
            Where a transform is undefined (e.g. a non-positive value of a
            log-space parameter); the message names the parameter.
        """
        return self._per_column(theta, "theta", "to_u")

    def from_unit_cube(self, Q: Any) -> np.ndarray:
        """Prior transform for nested sampling: unit-cube points to ``u``.

        Parameters
        ----------
        Q : array_like, shape (..., ndim)
            Points in ``[0, 1]^ndim``.

        Returns
        -------
        numpy.ndarray, shape (..., ndim)
            ``u`` with independent marginal prior CDFs equal to ``Q``.
        """
        return self._per_column(Q, "Q", "ppf_u")

    def sample_u(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Draw ``n`` independent prior points in the sampling space.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of randomness.
        n : int
            Number of points.

        Returns
        -------
        numpy.ndarray, shape (n, ndim)
        """
        return self.from_unit_cube(rng.random((int(n), self.ndim)))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Draw ``n`` independent prior points in physical units (:meth:`sample_u` mapped).

        Parameters
        ----------
        rng, n
            Source of randomness and number of points, as for :meth:`sample_u`.

        Returns
        -------
        numpy.ndarray, shape (n, ndim)
            Physical values.
        """
        return self.to_theta(self.sample_u(rng, n))

    # -- derived sets ----------------------------------------------------------------
    def override(self, changes: Mapping[str, Any]) -> PriorSet:
        """Return a copy with some priors replaced (API counterpart of the TOML file).

        Parameters
        ----------
        changes : mapping of name -> Prior or dict
            Names must already be in the set.

        Returns
        -------
        PriorSet
            A new set in the same parameter order; this one is unchanged.

        Raises
        ------
        PriorError
            For unknown names (the message lists the valid ones).
        """
        unknown = [k for k in changes if k not in self._priors]
        if unknown:
            raise PriorError(
                f"unknown parameter(s) {unknown} in prior overrides; this model's "
                f"parameters are {list(self._names)}"
            )
        new = dict(self._priors)
        for k, v in changes.items():
            new[k] = v
        return PriorSet(new)

    def scaled(self, factor: float, names: Iterable[str] | None = None) -> PriorSet:
        """Return a copy with the widths of the chosen priors multiplied by ``factor``.

        Parameters
        ----------
        factor : float
            Positive width multiplier, see :meth:`Prior.scaled`.
        names : iterable of str, optional
            Parameters to scale; default all.

        Returns
        -------
        PriorSet
        """
        chosen = list(self._names if names is None else names)
        unknown = [k for k in chosen if k not in self._priors]
        if unknown:
            raise PriorError(
                f"cannot scale unknown parameter(s) {unknown}; parameters are {list(self._names)}"
            )
        return self.override({k: self._priors[k].scaled(factor) for k in chosen})

    def subset(self, names: Iterable[str]) -> PriorSet:
        """Return the priors of ``names`` in the given order.

        Parameters
        ----------
        names : iterable of str

        Returns
        -------
        PriorSet
        """
        return PriorSet([(k, self[k]) for k in names])

    # -- serialisation ---------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Return ``{name: prior.to_dict()}`` in parameter order (TOML/JSON ready).

        Returns
        -------
        dict
        """
        return {k: p.to_dict() for k, p in self._priors.items()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> PriorSet:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : mapping of name -> dict

        Returns
        -------
        PriorSet
        """
        return cls(d)

    @classmethod
    def from_toml(
        cls, path: str | Path, base: PriorSet | None = None, *, table: str = "priors"
    ) -> PriorSet:
        """Read priors from the ``[priors.NAME]`` tables of a TOML file.

        Parameters
        ----------
        path : str or pathlib.Path
            TOML file, e.g. with ``[priors.E] dist = "loguniform" lo = 1e9 hi = 1e12``.
        base : PriorSet, optional
            Default priors of the model. When given, the file only overrides entries
            of ``base`` (unknown names are an error; order stays ``base``'s) and a
            file without the table returns ``base`` unchanged. When omitted, the
            file defines the whole set in file order.
        table : str, default "priors"
            Name of the top-level table holding the priors.

        Returns
        -------
        PriorSet

        Raises
        ------
        PriorError
            For unreadable TOML, a missing table (without ``base``), unknown names
            or invalid priors; the message names the file.
        """
        path = Path(path)
        data = read_toml(path, what="prior file", error=PriorError)
        section = data.get(table)
        if section is None:
            if base is not None:
                return base
            raise PriorError(f"{path}: no [{table}] table; add e.g. [{table}.E] entries")
        if not isinstance(section, dict) or not all(isinstance(v, dict) for v in section.values()):
            raise PriorError(
                f"{path}: [{table}] must contain one table per parameter, e.g. "
                f'[{table}.E] dist = "loguniform", lo = 1e9, hi = 1e12'
            )
        try:
            return cls(section) if base is None else base.override(section)
        except PriorError as exc:
            raise PriorError(f"{path}: {exc}") from None
