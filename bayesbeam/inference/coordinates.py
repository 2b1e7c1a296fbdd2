"""The coordinates the ensemble moves in, and emcee run in them.

With two or more damping laws the data fix the first mode's total damping tightly and
the split among the laws loosely; in the priors' log coordinates that ridge is curved
and emcee crosses it slowly. :class:`SamplerCoordinates` straightens it (log total
first-mode damping and log ratios, unit Jacobian); :func:`sample_in_coordinates` runs
the sampler there and returns the chain in the sampling space ``u`` of
:mod:`bayesbeam.stats.priors`, as every other part of the package reads it. The MAP
search (:mod:`bayesbeam.inference.optimum`) uses the same coordinates.
"""

from __future__ import annotations

import dataclasses
import weakref
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from bayesbeam.inference.parallel import ParallelLogProb
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.fem import (
    FEModel,
    first_mode_integrals,
    release_gain,
    spring_eigenvalue,
)
from bayesbeam.stats.convergence import autocorr_time, ess_rhat
from bayesbeam.stats.families import HalfNormal, LogNormal, LogUniform, Uniform
from bayesbeam.stats.moves import named_moves
from bayesbeam.stats.sampling import Chain, run_emcee

__all__ = ["PREBURN_STEPS", "ClampCoordinates", "Coordinates", "SamplerCoordinates",
           "chain_in_u", "sample_in_coordinates"]

#: :class:`ClampCoordinates`' tables of the first eigenvalue, per FE model (a problem's
#: matrices are built once and kept; the tables go with them).
_TABLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

#: Steps of the discarded first run that returns stranded walkers to the ensemble
#: (:func:`bayesbeam.stats.sampling.preburn_walkers`); ~10 % of a typical fit's steps.
PREBURN_STEPS = 200


class Coordinates(Protocol):
    """What a coordinate map offers the sampler and the MAP search.

    ``to_v`` / ``to_u`` map points (shape (..., ndim) kept) between the sampling space
    ``u`` and the sampler's coordinates ``v``; ``log_jacobian(V)`` is ``log |∂u/∂v|``,
    shape (...,); ``identity`` is True when ``v = u``; ``free`` lists the columns of
    ``v`` that are unbounded (a bound in ``u`` is not a bound on them); ``describe()``
    names the coordinates in one line (the settings record; a checkpoint records it).
    """

    identity: bool

    def to_v(self, U: np.ndarray) -> np.ndarray: ...  # noqa: D102

    def to_u(self, V: np.ndarray) -> np.ndarray: ...  # noqa: D102

    def log_jacobian(self, V: np.ndarray) -> np.ndarray: ...  # noqa: D102

    @property
    def free(self) -> np.ndarray: ...  # noqa: D102

    def describe(self) -> str: ...  # noqa: D102


class SamplerCoordinates:
    """Coordinates the ensemble moves in: the damping laws' total and split.

    With two or more damping laws, the data fix the first mode's total damping ratio
    ζ1 = Σ_j ζ1_j very tightly and the split among the laws only loosely (through the
    higher modes). In the log coordinates ``u_j = log x_j`` of the priors that ridge
    is a curved (hyperbolic) valley, which the affine-invariant moves of emcee cross
    slowly: integrated autocorrelation times ~70 steps for ``viscous+kv`` and ~110 for
    ``viscous+sh`` on the benchmark trial. The sampler therefore moves in

        v_tot = log Σ_j exp(u_j + c_j),     w_j = u_j - u_1  (j >= 2),

    with ``exp(u_j + c_j)`` the law's first-mode damping ratio: ``c_j`` is the log of
    ζ1 per unit of the law's parameter, from the first mode of the beam's own FE model
    (:func:`~bayesbeam.physics.fem.first_mode_integrals`: ``g/(2ω1)`` for gamma,
    ``κ/(2ω1)`` for c_d, ``κ/(2 I ω1)`` for eta, the hysteresis law's Kelvin–Voigt
    equivalent of physics.md §2), at the prior's median E and the beam as declared.
    Both the total and the log ratios are straight in these coordinates; τ drops to
    20–30 steps. The map is a bijection with unit Jacobian
    (``det ∂(v_tot, w)/∂u = Σ_j p_j = 1``, ``p_j`` the shares), so the density is
    unchanged: ``log_prob_v(v) = log_prob(u(v))``.

    The scales must be exact *relative to one another*, not only in size: at fixed
    ``v_tot`` a move of the split changes the true ζ1 by ``(ε_1 - ε_2) Δp`` if the laws'
    scales are off by ``ε_j``, and ζ1 is what the data fix best. The uniform-beam
    formulas (``gamma/(2 rhoA ω1)``) are 5-10 % off on the shipped beam 2 (a lighter
    cut-out segment and a tip mass), which tilted the split against the total by
    hundreds of nats per unit of log ratio. ζ1 of every law scales as ``E^(-1/2)`` at
    fixed structure, so fixed scales keep the split exact at any E.

    The structure sampled beside the laws moves the scales too, though less: a point
    mass lowers the viscous scale ``g/ω1`` by its share of the modal mass and the
    Kelvin–Voigt scale ``κ/ω1 = ω1/E`` by the same factor to first order (Rayleigh),
    so only the second order tilts the split (10 % of the beam's mass at 0.85 L: a
    unit move of the split changes ζ1 by 1.2e-4); a stiffness gradient reshapes the
    curvature that ``KV`` weighs (gradient 0.9: 8e-3). Their posteriors are narrow, so
    ``at`` (the MAP, where the walkers start) takes the scales from the first mode of
    the structure there (:meth:`~bayesbeam.physics.forward.Forward.first_mode`:
    masses, gradient, clamp) instead of the beam as declared, exact at that point; it
    is a fixed point, so the map stays a bijection with unit Jacobian.

    Laws whose prior is not on ``log x`` (a user's Uniform or Normal override), and
    models with fewer than two laws, are left in ``u``.

    Where the model samples E and a clamp spring, those two move in the coordinates of
    :class:`ClampCoordinates` (log ω1² and log k), and the laws' scales follow each
    point's own ω1 and mode shape (its ``r = k/E``; tabulated there) instead of the
    prior median's: along that map's ridge E changes by tens of % at fixed ω1, and the
    spring takes a share of the strain energy that the Kelvin–Voigt law does not damp,
    which would bend the total-damping ridge again. The map is then block-triangular
    (the laws' part has unit Jacobian at fixed E and k), so its Jacobian is the clamp
    map's. With ``at``, the tables (of the beam as declared) are corrected by the
    constant log ratio of the exact integrals at ``at`` to the table's at its ``k/E``.

    Parameters
    ----------
    problem : Problem
    at : ndarray, shape (ndim,), optional
        A point in the sampling space ``u`` whose structure sets the laws' scales
        (default: the prior medians and the beam as declared). A point whose first
        mode cannot be computed (e.g. outside the priors) falls back to the default.
    """

    _LOG = (LogUniform, LogNormal, HalfNormal)
    #: Each law's first-mode integral (0: ``g``, 1: ``κ``) and its log factor in ζ1 per
    #: unit parameter beside it (``ζ1 = x · factor · integral / ω1``).
    _LAWS = {"gamma": (0, np.log(0.5)), "c_d": (1, np.log(0.5)), "eta": (1, None)}

    def __init__(self, problem: Problem, at: np.ndarray | None = None) -> None:
        beam = problem.trial.beam
        pri = problem.priors
        idx = [problem.names.index(n) for n in self._LAWS
               if n in problem.names and isinstance(pri[n], self._LOG)]
        self.group = np.array(idx if len(idx) >= 2 else [], dtype=int)
        self.law_names = tuple(problem.names[j] for j in self.group)
        self.kinds = np.array([self._LAWS[n][0] for n in self.law_names], dtype=int)
        self.offset = np.array([np.log(0.5 / beam.I) if self._LAWS[n][1] is None
                                else self._LAWS[n][1] for n in self.law_names])
        self.clamp = ClampCoordinates.for_problem(problem)
        self.coupled = self.clamp
        self.c = np.zeros(0)
        self.delta = np.zeros(self.group.size)  # the clamp tables' correction at ``at``
        self.at_point = False
        if self.group.size:
            ref = None if at is None else self._integrals_at(problem, at)
            if ref is None:
                self.c = self.offset + self._reference_integrals(problem)
            else:
                log_integral, log_w1 = ref
                self.c = self.offset + log_integral - log_w1
                self.at_point = True
                if self.clamp is not None:  # the tables' scales at ``at``, made exact there
                    cl = self.clamp
                    u = np.asarray(at, dtype=float)
                    s = u[cl.ik] - u[cl.iE]
                    table = (cl.mode_integrals(s)[self.kinds]
                             - 0.5 * (u[cl.iE] + cl.h(s)[0]))
                    self.delta = log_integral - log_w1 - table

    def _integrals_at(self, problem: Problem, at: np.ndarray
                      ) -> tuple[np.ndarray, float] | None:
        """``log`` of each law's first-mode integral and ``log ω1`` at ``at``, or None."""
        u = np.asarray(at, dtype=float).reshape(1, -1)
        if u.shape[1] != problem.ndim or not np.all(np.isfinite(u)):
            return None
        P = problem.forward_params(problem.theta(u))
        if not problem.forward.check(P)[0]:
            return None
        w1, phi = problem.forward.first_mode(P)
        fe = problem.forward.fe
        integral = np.array([phi[0] @ fe.G @ phi[0], phi[0] @ fe.KV @ phi[0]])[self.kinds]
        if not (np.isfinite(w1[0]) and w1[0] > 0 and np.all(integral > 0)):
            return None
        return np.log(integral), float(np.log(w1[0]))

    def _reference_integrals(self, problem: Problem) -> np.ndarray:
        """``log(integral/ω1)`` per law at the prior medians and the beam as declared."""
        pri = problem.priors

        def median(name: str) -> float:
            return float(pri[name].from_u(pri[name].ppf_u(0.5)))  # fixed: resume-safe

        E_c = median("E")
        fe = problem.forward.fe
        ratio = None
        if fe.root_dof:
            k = (median("root_spring") if "root_spring" in problem.names
                 else problem.trial.beam.root_spring)
            ratio = [k / E_c]
        mu, g, kappa = first_mode_integrals(fe, ratio)
        integral = np.array([g[0], kappa[0]])[self.kinds]
        return np.log(integral) - 0.5 * np.log(E_c * mu[0])

    @classmethod
    def on_columns(cls, group: Any, c: Any, *, offset: Any = None, kinds: Any = None,
                   coupled: ClampCoordinates | None = None) -> SamplerCoordinates:
        """Make the laws' map on other columns (e.g. one trial's laws inside a joint fit).

        It maps the laws' columns only: the clamp map ``coupled``, whose E and ω1 the
        scales follow, is applied by the caller (:meth:`laws_to_v`, :meth:`laws_to_u`).

        Parameters
        ----------
        group : sequence of int
            Columns of the laws (two or more).
        c : sequence of float
            Their log first-mode damping ratio per unit parameter at the reference
            (as ``self.c``), used without ``coupled``.
        offset, kinds : array_like, optional
            Each law's log factor and first-mode integral (as ``self.offset`` and
            ``self.kinds``); needed with ``coupled``.
        coupled : ClampCoordinates, optional
            The clamp map of the E and spring columns the scales follow.

        Returns
        -------
        SamplerCoordinates
        """
        out = cls.__new__(cls)
        out.group = np.asarray(group, dtype=int)
        out.c = np.asarray(c, dtype=float)
        out.clamp = None
        out.coupled = coupled
        out.law_names = tuple(f"column {j}" for j in out.group)
        if out.group.size == 1 or out.group.shape != out.c.shape:
            raise ValueError("on_columns needs two or more columns and one scale per column")
        if coupled is not None and (offset is None or kinds is None):
            raise ValueError("on_columns with a clamp map needs each law's offset and kind")
        # offset and kinds are read only with a clamp map (_scales)
        out.offset = None if offset is None else np.asarray(offset, dtype=float)
        out.kinds = None if kinds is None else np.asarray(kinds, dtype=int)
        out.delta = np.zeros(out.group.size)
        out.at_point = False
        return out

    def _scales(self, U: np.ndarray, V: np.ndarray) -> np.ndarray:
        """Return the laws' ``c_j``, shape (..., n_laws) or (n_laws,).

        Fixed, or, with a clamp map, at each point's log ω1² (``V``) and the first
        mode's integrals at its ``r = k/E`` (``U``).
        """
        cl = self.coupled
        if cl is None:
            return self.c
        integrals = cl.mode_integrals(U[..., cl.ik] - U[..., cl.iE])[..., self.kinds]
        return self.offset + integrals + self.delta - 0.5 * V[..., cl.iE][..., None]

    def laws_to_v(self, U: np.ndarray, V: np.ndarray) -> None:
        """Write the laws' sampler coordinates into ``V`` (in place) from ``U``.

        ``V`` holds the clamp map's ``v_E`` already when the scales are ``coupled``.
        """
        g = self.group
        if g.size:
            # numpy's ufunc reduction: scipy's logsumexp cost ~0.2 ms per call here, ~12 %
            # of a viscous+kv fit's sampling on 1280 samples.
            V[..., g[0]] = np.logaddexp.reduce(U[..., g] + self._scales(U, V), axis=-1)
            V[..., g[1:]] = U[..., g[1:]] - U[..., g[:1]]

    def laws_to_u(self, V: np.ndarray, U: np.ndarray) -> None:
        """Write the laws' sampling-space values into ``U`` (in place) from ``V``.

        ``U`` holds log E already (the clamp map's inverse) when the scales are ``coupled``.
        """
        g = self.group
        if g.size:
            w = np.zeros(V.shape[:-1] + (g.size,))
            w[..., 1:] = V[..., g[1:]]
            U[..., g] = w + (V[..., g[0]]
                             - np.logaddexp.reduce(w + self._scales(U, V), axis=-1))[..., None]

    @property
    def identity(self) -> bool:
        """True when the sampler works in ``u`` itself."""
        return self.group.size == 0 and self.clamp is None

    def to_v(self, U: np.ndarray) -> np.ndarray:
        """Map sampling-space points to sampler coordinates, shape (..., ndim) kept."""
        U = np.asarray(U, dtype=float)
        V = U.copy() if self.clamp is None else self.clamp.to_v(U)
        self.laws_to_v(U, V)
        return V

    def to_u(self, V: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_v`."""
        V = np.asarray(V, dtype=float)
        U = V.copy() if self.clamp is None else self.clamp.to_u(V)
        self.laws_to_u(V, U)
        return U

    @property
    def free(self) -> np.ndarray:
        """Columns of ``v`` with no bound: the grouped laws (their total and ratios), v_E."""
        return self.group if self.clamp is None else np.union1d(self.group, self.clamp.free)

    def log_jacobian(self, V: np.ndarray) -> np.ndarray:
        """``log |∂u/∂v|``, shape ``V.shape[:-1]``: the clamp map's (the laws' map has 1).

        The clamp map reads only the E and spring columns, which the laws' map leaves
        as they are; the laws' map depends on those columns but not they on it (a
        block-triangular Jacobian).
        """
        if self.clamp is None:
            return np.zeros(np.shape(V)[:-1])
        return self.clamp.log_jacobian(V)

    def describe(self) -> str:
        """One line for the settings record."""
        parts = []
        if self.group.size:
            # "FE first mode": the scales of fem.first_mode_integrals (a checkpoint made
            # with the uniform-beam scales of earlier versions is refused, not resumed).
            where = " at the start point" if self.at_point else ""
            parts.append("(" + ", ".join(self.law_names) + ") as log total first-mode "
                         f"damping (FE first mode{where}) and log ratios")
        if self.clamp is not None:
            parts.append(self.clamp.describe())
        return "u with " + "; ".join(parts) if parts else "u"


class ClampCoordinates:
    """Coordinates for E and a clamp spring: log ω1² and log k.

    With the root spring k sampled beside E and the first mode the only one in the
    record's band, the data fix ``ω1² = E μ(k/E)`` (:func:`~bayesbeam.physics.fem.
    spring_eigenvalue`) and little else of the pair: a ridge from a stiff clamp (ω1 set
    by E alone) to a soft one (ω1 set by k alone), curved in ``(log E, log k)``, along
    which emcee's moves crawl (the shipped beam 2, one mode below its 100 Hz band: a
    narrow, wrong, unconverged interval on E). The sampler therefore moves in

        v_E = log E + h(log k - log E),    v_k = log k,

    with ``h(s) = log μ(e^s)``, so that ``v_E = log ω1²`` exactly for the beam as
    declared (its masses, spanwise E and I; the nominal values of any other sampled
    structure) and the ridge is the straight line ``v_E = const``. The map is a
    bijection: ``∂v_E/∂log E = 1 - e(s)`` with the elasticity ``e = h'`` in (0, 1), so
    ``log |∂u/∂v| = -log(1 - e(s))``. The inverse solves ``x + h(log k - x) = v_E`` for
    ``x = log E`` by Newton's method, which converges monotonically from the left
    (the left side is increasing and concave in x, since e decreases in s).

    ``h`` is the cubic Hermite interpolant of the exact ``log μ`` and elasticity at
    :data:`GRID_PER_DECADE` points per decade of ``κ = k L/(E I)`` over
    :data:`KAPPA_RANGE`, and linear with the end slopes outside: a smooth function whose
    own derivative is the Jacobian's ``e`` (the map is exact whatever the
    interpolation error, which only makes the ridge slightly less straight), and with
    ``e < 1`` everywhere the map is a bijection of the plane (the interpolant's slope
    may dip a few 1e-6 below 0 at the stiff end, where e itself is ~1e-5: harmless).

    With a release initial condition the tip deflection ``w0`` moves as the first
    mode's amplitude at the sensor, ``v_w0 = w0 g(s)/g_stiff``
    (:func:`~bayesbeam.physics.fem.release_gain`, relative to the table's stiff end):
    the static shape released, and so the share of it in mode 1, changes along the
    ridge (by 0.2-2 % on beam 2), which the data see at fixed ω1. ``log |∂u/∂v|``
    then gains ``-log(g/g_stiff)``.

    Parameters
    ----------
    columns : tuple of int
        Columns of ``log E`` and ``log k`` in ``u``.
    fe : FEModel
        The beam's matrices with a root rotation dof.
    kappa_scale : float
        ``L/I`` in 1/m³, so that ``κ = kappa_scale · k/E``.
    release : (int, float), optional
        Column of ``w0`` (sampled as itself) and the sensor position in m from the
        clamp; None leaves every other column as it is.
    """

    #: κ = k L/(E I) of the table: the default prior spans κ of 0.25 to 4e4 (E and k
    #: each at either end of theirs); the table reaches 25x beyond at both ends. At the
    #: soft end μ's relative accuracy falls as its condition number grows (~1e-6 at
    #: κ = 0.01 on 32 elements), at the stiff end e is ~1e-5 and stays below the
    #: interpolant's own error further out.
    KAPPA_RANGE = (1e-2, 1e6)
    #: Nodes per decade. The ridge's width in v_E is what matters: one mode in band on
    #: the shipped beam 2 (5 s at 17.6 Hz) fixes log ω1² to a sd of 5e-6, so the table
    #: must follow log μ far closer than that or the straightened ridge wiggles across
    #: its own width: 6 per decade gave up to 7e-6 (median 2e-7), 24 per decade gives
    #: 3e-7 (median 1e-8; FE rounding), measured against direct eigen-solves.
    GRID_PER_DECADE = 24
    #: Newton steps of the inverse and its tolerance on x = log E.
    MAX_NEWTON, NEWTON_TOL = 60, 1e-13

    def __init__(self, columns: tuple[int, int], fe: FEModel, kappa_scale: float, *,
                 release: tuple[int, float] | None = None) -> None:
        self.iE, self.ik = (int(c) for c in columns)
        lo, hi = (np.log10(k) for k in self.KAPPA_RANGE)
        n = int(round((hi - lo) * self.GRID_PER_DECADE))
        kappa = np.logspace(lo, hi, n + 1)
        r = kappa / kappa_scale
        table = _TABLES.setdefault(fe, {})
        key = (float(kappa_scale), n)
        if key not in table:  # ~0.1 s: the MAP search builds this map once per search
            table[key] = spring_eigenvalue(fe, r)
        mu, e = table[key]
        s = np.log(r)
        self._s0, self._ds = float(s[0]), float(s[1] - s[0])
        self._y, self._m = np.log(mu), e
        # The first mode's viscous and Kelvin–Voigt integrals along the ridge, on which
        # the damping laws' scales depend (SamplerCoordinates; both change with the mode
        # shape as the clamp softens): log values and their slopes in s.
        key_i = (*key, "integrals")
        if key_i not in table:
            table[key_i] = first_mode_integrals(fe, r)[1:]
        self._mi = np.log(np.stack(table[key_i], axis=1))  # (nodes, 2): log g, log κ
        self._mim = np.gradient(self._mi, self._ds, axis=0)
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.iw: int | None = None
        if release is not None:
            key_g = (*key, float(release[1]))
            if key_g not in table:
                table[key_g] = release_gain(fe, r, release[1])
            g = table[key_g]
            if np.all(g > 0):  # a sensor at a node of mode 1 would see none of it
                self.iw = int(release[0])
                self._g = np.log(g / g[-1])  # 0 at the stiff end of the table
                self._gm = np.gradient(self._g, self._ds)

    @classmethod
    def for_problem(cls, problem: Problem, e_col: int | None = None,
                    k_col: int | None = None) -> ClampCoordinates | None:
        """Return the map for a problem sampling E and ``root_spring`` in log x, else None.

        Parameters
        ----------
        problem : Problem
        e_col, k_col : int, optional
            Their columns in the sampler's space (default: the problem's own).

        Returns
        -------
        ClampCoordinates or None
        """
        names, pri = problem.names, problem.priors
        if not ("E" in names and "root_spring" in names
                and all(isinstance(pri[n], SamplerCoordinates._LOG)
                        for n in ("E", "root_spring"))):
            return None
        fe = problem.forward.fe
        beam = problem.trial.beam
        cols = (names.index("E") if e_col is None else e_col,
                names.index("root_spring") if k_col is None else k_col)
        release = None
        w0 = pri["w0"] if "w0" in names else None
        if (e_col is None and getattr(problem.forward, "initial", None) == "release"
                and isinstance(w0, Uniform) and w0.transform == "identity"):
            release = (names.index("w0"), beam.sensor_x)
        return cls(cols, fe, beam.length / beam.I, release=release)

    identity = False

    def h(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``h(s) = log μ(e^s)`` and its slope ``e(s)``, shape of ``s`` each."""
        return self._hermite(self._y, self._m, s)

    def _hermite(self, y: np.ndarray, m: np.ndarray, s: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Evaluate the cubic Hermite interpolant of node values ``y`` and slopes ``m``.

        Evaluated directly on the uniform table (a general spline's call costs ~10x
        more, and the inverse map evaluates this ~10 times per batch); straight on with
        the end slopes beyond the table. Returns the value and its derivative.
        """
        s = np.asarray(s, dtype=float)
        d = self._ds
        last = y.size - 1
        z = (s - self._s0) / d
        i = np.clip(np.floor(np.nan_to_num(z)), 0, last - 1).astype(int)
        t = np.clip(z - i, 0.0, 1.0)
        t2 = t * t
        y0, y1, m0, m1 = y[i], y[i + 1], m[i] * d, m[i + 1] * d
        val = (y0 * (2 * t2 * t - 3 * t2 + 1) + m0 * (t2 * t - 2 * t2 + t)
               + y1 * (3 * t2 - 2 * t2 * t) + m1 * (t2 * t - t2))
        slope = ((y1 - y0) * (6 * t - 6 * t2) + m0 * (3 * t2 - 4 * t + 1)
                 + m1 * (3 * t2 - 2 * t)) / d
        below, above = z < 0, z > last
        val = np.where(below, y[0] + m[0] * d * z, val)
        val = np.where(above, y[-1] + m[-1] * d * (z - last), val)
        slope = np.where(below, m[0], np.where(above, m[-1], slope))
        return val, slope

    def mode_integrals(self, s: np.ndarray) -> np.ndarray:
        """Log of the first mode's ``g`` and ``κ`` at ``s = log(k/E)``, shape (..., 2).

        :func:`~bayesbeam.physics.fem.first_mode_integrals` on the table, cubic Hermite
        with finite-difference slopes.
        """
        return np.stack([self._hermite(self._mi[:, j], self._mim[:, j], s)[0]
                         for j in range(2)], axis=-1)

    def _gain(self, s: np.ndarray) -> np.ndarray:
        """Return the log release gain relative to the stiff clamp's, shape of ``s``."""
        return self._hermite(self._g, self._gm, s)[0]

    def to_v(self, U: np.ndarray) -> np.ndarray:
        """Map sampling-space points to sampler coordinates, shape (..., ndim) kept."""
        U = np.asarray(U, dtype=float)
        V = U.copy()
        sv = U[..., self.ik] - U[..., self.iE]
        hv, _ = self.h(sv)
        V[..., self.iE] = U[..., self.iE] + hv
        if self.iw is not None:
            V[..., self.iw] = U[..., self.iw] * np.exp(self._gain(sv))
        return V

    def _log_e(self, V: np.ndarray) -> np.ndarray:
        """Solve ``x + h(log k - x) = v_E`` for ``x = log E``, shape ``V.shape[:-1]``."""
        vE, uk = V[..., self.iE], V[..., self.ik]
        last = self._last
        if last is not None and last[0].shape == vE.shape + (2,) and np.array_equal(
                last[0], np.stack([vE, uk], axis=-1)):
            return last[1]  # log_jacobian at the points to_u just mapped
        # Start at the stiff end of the table: h there bounds h everywhere (h is
        # increasing and, but for the interpolant's wiggle at the stiff end, concave),
        # so the start is left of the root, and Newton on the increasing, concave
        # left side then climbs to it without overshooting.
        s1, h1, e1 = self._s0 + self._ds * (self._y.size - 1), self._y[-1], self._m[-1]
        x = (vE - h1 - e1 * (uk - s1)) / (1.0 - e1)
        x = np.where(np.isfinite(x), x, np.nan)
        for _ in range(self.MAX_NEWTON):
            hv, e = self.h(uk - x)
            step = (vE - x - hv) / (1.0 - e)
            x = x + step
            if not np.any(np.abs(step) > self.NEWTON_TOL):
                break
        self._last = (np.stack([vE, uk], axis=-1), x)
        return x

    def to_u(self, V: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_v`."""
        V = np.asarray(V, dtype=float)
        U = V.copy()
        with np.errstate(invalid="ignore"):
            U[..., self.iE] = self._log_e(V)
            if self.iw is not None:
                U[..., self.iw] = V[..., self.iw] * np.exp(
                    -self._gain(V[..., self.ik] - U[..., self.iE]))
        return U

    @property
    def free(self) -> np.ndarray:
        """Columns of ``v`` with no bound: ``v_E`` and ``v_w0`` (their bounds are curves)."""
        return np.array([self.iE] if self.iw is None else [self.iE, self.iw])

    def log_jacobian(self, V: np.ndarray) -> np.ndarray:
        """``log |∂u/∂v| = -log(1 - e(log k - log E))``, shape ``V.shape[:-1]``."""
        V = np.asarray(V, dtype=float)
        with np.errstate(invalid="ignore"):
            sv = V[..., self.ik] - self._log_e(V)
            _, e = self.h(sv)
            out = -np.log1p(-e)
            if self.iw is not None:  # w0 = v_w0 / gain: a factor 1/gain
                out = out - self._gain(sv)
        return out

    def describe(self) -> str:
        """One line for the settings record."""
        return "E as log first-mode ω² beside log root_spring" + (
            "; w0 as the first mode's release amplitude" if self.iw is not None else "")


def chain_in_u(chain: Chain, u_samples: np.ndarray, log_prob: np.ndarray | None = None) -> Chain:
    """Return the chain moved back from the sampler's coordinates to the sampling space ``u``.

    Convergence was judged in the sampler's coordinates; τ, ESS and R-hat are reported
    for the parameters themselves, with the estimators of the stopping rule (tol 0: τ
    as estimated, no length requirement here).

    Parameters
    ----------
    chain : Chain
    u_samples : ndarray, shape (nsteps, nwalkers, ndim)
    log_prob : ndarray, shape (nsteps, nwalkers), optional
        The log density in ``u`` where the map's Jacobian is not 1.

    Returns
    -------
    Chain
    """
    tau, _ = autocorr_time(u_samples, 0.0)
    ess, rhat = ess_rhat(u_samples)
    lp = chain.log_prob if log_prob is None else log_prob
    return dataclasses.replace(chain, samples=u_samples, log_prob=lp, tau=tau, ess=ess,
                               rhat=rhat)



def sample_in_coordinates(log_prob: Callable[[np.ndarray], np.ndarray], coords: Coordinates,
                          u0: np.ndarray, *, moves: str = "de", helpers: int = 0,
                          extra_moves: Sequence[tuple[Any, float]] = (),
                          **kwargs: Any) -> Chain:
    """Run emcee (:func:`~bayesbeam.stats.sampling.run_emcee`) in ``coords``.

    The walkers start at ``coords.to_v(u0)`` and move on ``log_prob(u(v)) + log|∂u/∂v|``
    with the proposal mixture ``moves`` (default the differential-evolution mixture of
    :func:`~bayesbeam.stats.moves.de_moves`); the chain comes back in ``u``
    (:func:`chain_in_u`), its log density in ``u``.

    Parameters
    ----------
    log_prob : callable
        Vectorised log density in ``u``, ``(k, ndim) -> (k,)``.
    coords : Coordinates
        e.g. :class:`SamplerCoordinates`.
    u0 : ndarray, shape (nwalkers, ndim)
        Initial walkers in ``u``.
    moves : str
        A name of :data:`~bayesbeam.stats.moves.MOVE_SETS`.
    helpers : int
        Processes that share each batch of ``log_prob`` with this one
        (:class:`~bayesbeam.inference.parallel.ParallelLogProb`; ``log_prob`` must then
        be picklable, e.g. a problem's bound ``log_prob``). The chain is the same.
    extra_moves : sequence of (emcee move, float)
        Moves mixed in with these weights (summing below 1); the named mixture's
        weights are scaled to the rest (e.g. the pooled spreads' walk of a joint fit).
    **kwargs
        Passed to :func:`~bayesbeam.stats.sampling.run_emcee` (``seed``, ``max_steps``,
        ``target_ess``, ``names``, ``preburn``, ...).

    Returns
    -------
    Chain
    """
    with ParallelLogProb(log_prob, helpers=helpers) as shared:
        def log_prob_v(V: np.ndarray) -> np.ndarray:
            return shared(coords.to_u(V)) + coords.log_jacobian(V)

        w_extra = sum(w for _, w in extra_moves)
        if not 0.0 <= w_extra < 1.0:
            raise ValueError(f"extra_moves' weights must sum to [0, 1), got {w_extra}")
        mix = [(m, w * (1.0 - w_extra)) for m, w in named_moves(moves)] + list(extra_moves)
        chain = run_emcee(log_prob_v, coords.to_v(u0), moves=mix,
                          space=coords.describe(), **kwargs)
    if coords.identity:
        return chain
    return chain_in_u(chain, coords.to_u(chain.samples),
                      chain.log_prob - coords.log_jacobian(chain.samples))
