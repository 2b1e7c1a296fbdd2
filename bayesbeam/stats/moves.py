"""Ensemble proposal moves beyond (or correcting) emcee's release.

* :class:`SnookerMove` — the differential-evolution snooker update (ter Braak & Vrugt
  2008, Stat. Comput. 18, 435, eqs. 4-5). emcee 3.1.6's ``DESnookerMove`` (its latest
  release) normalises the projection direction by the square root of the distance and
  halves the Jacobian term, so that its chain does not have the target as its
  stationary law (fixed upstream in emcee pull request 531, not released):
  ``tests/stats/test_moves.py`` shows the package's mixture reproducing a closed-form
  posterior where the released move's is ~2x off in a scale parameter's median.
* :class:`ReparamWalkMove` — random-walk steps of some coordinates of another
  parametrisation (a pooled spread at fixed non-centred values), where the ensemble's
  own coordinates make a funnel.
* the named mixtures of the fits (:func:`de_moves`, :data:`MOVE_SETS`,
  :func:`named_moves`).

A move is a small object with one job, as emcee's own: it proposes and returns the
log-ratio of the proposal densities; the ensemble sampler accepts or rejects.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import emcee
import numpy as np
from emcee.moves.mh import MHMove
from emcee.moves.red_blue import RedBlueMove

__all__ = ["MOVE_SETS", "ReparamWalkMove", "SnookerMove", "de_moves", "named_moves"]


class SnookerMove(RedBlueMove):
    r"""Differential-evolution snooker update (ter Braak & Vrugt 2008).

    For a walker ``x``, three walkers ``z, z1, z2`` are drawn from the complementary
    sub-ensembles (four splits, as in emcee). With the unit vector
    ``e = (x - z) / |x - z|`` the proposal is

    .. math:: x' = x + \gamma\, e\, e^\top (z_1 - z_2),

    a move along the line through ``z``; its acceptance carries the factor
    ``(|x' - z| / |x - z|)^(d - 1)`` (ter Braak & Vrugt 2008, eq. 5) for the change of the
    line's position on the sphere around ``z``.

    Parameters
    ----------
    gammas : float, default 1.7
        Step factor γ (the reference's recommended value).
    """

    def __init__(self, gammas: float = 1.7) -> None:
        self.gammas = float(gammas)
        super().__init__(nsplits=4)

    def get_proposal(self, s: np.ndarray, c: list[np.ndarray],
                     random: np.random.RandomState) -> tuple[np.ndarray, np.ndarray]:
        """Propose for the walkers ``s`` (Ns, d) from the complementary sets ``c``.

        Parameters
        ----------
        s : ndarray, shape (Ns, d)
            Walkers to move.
        c : list of ndarray
            The other three sub-ensembles, each (Nc_j, d).
        random : numpy.random.RandomState
            The sampler's random state (emcee passes its own).

        Returns
        -------
        q : ndarray, shape (Ns, d)
            Proposed positions.
        factors : ndarray, shape (Ns,)
            ``log q(x | x') - log q(x' | x)`` = ``(d - 1) log(|x' - z| / |x - z|)``.
        """
        ns, ndim = s.shape
        rows = np.arange(ns)
        # One walker from each complementary set, in random order (emcee's draw).
        w = np.stack([cj[random.randint(len(cj), size=ns)] for cj in c[:3]])  # (3, Ns, d)
        order = np.argsort(random.rand(ns, 3), axis=1)
        z, z1, z2 = (w[order[:, k], rows] for k in range(3))
        delta = s - z
        norm = np.linalg.norm(delta, axis=1)
        q = s.copy()
        factors = np.zeros(ns)
        # A walker on top of z has no direction: it stays (a null move, always valid).
        ok = norm > 0
        e = delta[ok] / norm[ok, None]
        step = self.gammas * np.einsum("ij,ij->i", e, z1[ok] - z2[ok])
        q[ok] = s[ok] + step[:, None] * e
        with np.errstate(divide="ignore"):
            factors[ok] = (ndim - 1.0) * (np.log(np.linalg.norm(q[ok] - z[ok], axis=1))
                                          - np.log(norm[ok]))
        return q, factors


class ReparamWalkMove(MHMove):
    r"""Random-walk Metropolis steps of chosen coordinates of ``u``, carried into ``v``.

    The ensemble samples in coordinates ``v(u)`` (e.g. a pooled parameter's trial values
    centred, ``v_i = m + s z_i``). Some directions of the posterior are easy in ``u`` and
    hard in ``v``: a population spread ``s`` near zero is a funnel in the centred
    coordinates, each trial's value pinned to the median as ``s`` shrinks, while in the
    non-centred ``u`` a step of ``log s`` at fixed ``z_i`` is free. This move proposes
    ``u' = u + δ e_cols`` (δ Gaussian, its sd drawn from ``scales`` per walker: a
    symmetric mixture), maps it to ``v' = v(u')`` and corrects for the map:

    .. math:: \log\frac{q_v(v \mid v')}{q_v(v' \mid v)}
              = \log\left|\frac{\partial u}{\partial v}\right|(v)
              - \log\left|\frac{\partial u}{\partial v}\right|(v'),

    so that, on the ensemble's target ``p_v(v) = p_u(u) |∂u/∂v|``, the acceptance is
    ``p_u(u') / p_u(u)`` (interweaving the two parametrisations, Yu & Meng 2011).

    Parameters
    ----------
    to_u, to_v : callable
        The coordinate maps, ``(k, ndim) -> (k, ndim)``, inverse to each other.
    log_jacobian : callable
        ``log |∂u/∂v|`` at points ``v``, ``(k, ndim) -> (k,)``.
    columns : sequence of int
        Columns of ``u`` to step (all together).
    scales : sequence of float, default (0.1, 0.5, 2.0)
        Step sds in ``u`` units, one drawn per walker and proposal.
    """

    def __init__(self, to_u: Callable[[np.ndarray], np.ndarray],
                 to_v: Callable[[np.ndarray], np.ndarray],
                 log_jacobian: Callable[[np.ndarray], np.ndarray],
                 columns: Sequence[int], scales: Sequence[float] = (0.1, 0.5, 2.0)) -> None:
        self.to_u, self.to_v, self.log_jacobian = to_u, to_v, log_jacobian
        self.columns = np.asarray(columns, dtype=int)
        self.scales = np.asarray(scales, dtype=float)
        if self.columns.size == 0 or np.any(self.scales <= 0):
            raise ValueError("ReparamWalkMove needs at least one column and positive scales")
        super().__init__(self._propose)

    def _propose(self, V: np.ndarray, random: np.random.RandomState
                 ) -> tuple[np.ndarray, np.ndarray]:
        k = V.shape[0]
        U = np.array(self.to_u(V), dtype=float)
        sd = self.scales[random.randint(self.scales.size, size=k)]
        U[:, self.columns] += sd[:, None] * random.randn(k, self.columns.size)
        with np.errstate(over="ignore", invalid="ignore"):  # such rows are rejected below
            V2 = np.asarray(self.to_v(U), dtype=float)
            factors = np.asarray(self.log_jacobian(V), float) - np.asarray(
                self.log_jacobian(V2), float)
        # A proposal the maps cannot carry (overflow): rejected, never NaN.
        bad = ~(np.all(np.isfinite(V2), axis=1) & np.isfinite(factors))
        V2[bad], factors[bad] = V[bad], -np.inf
        return V2, factors


def de_moves() -> list[tuple[Any, float]]:
    """Return the proposal moves of the package's fits: differential evolution (+ snooker).

    Differential-evolution proposals (ter Braak 2006; ter Braak & Vrugt 2008) mix much
    faster than emcee's default stretch move on the near-Gaussian, correlated beam
    posteriors (integrated autocorrelation times about 3-4x shorter in our runs;
    ``studies/bench_moves.py`` measures ESS per second against the alternatives of
    :data:`MOVE_SETS`). The snooker update is the package's
    :class:`SnookerMove`: emcee 3.1.6's ``DESnookerMove`` does not
    leave the target invariant (module docstring).

    Returns
    -------
    list of (emcee.moves.Move, float)
        The ``moves`` argument of :func:`~bayesbeam.stats.sampling.run_emcee` (new move
        objects on each call).
    """
    return [(emcee.moves.DEMove(), 0.8), (SnookerMove(), 0.2)]


#: Named proposal mixtures (``sampler_options={"moves": NAME}``); ``"de"`` is the default.
MOVE_SETS: dict[str, Callable[[], list[tuple[Any, float]]]] = {
    "de": de_moves,
    "stretch": lambda: [(emcee.moves.StretchMove(), 1.0)],
    "de+stretch": lambda: [(emcee.moves.DEMove(), 0.5), (emcee.moves.StretchMove(), 0.5)],
}


def named_moves(name: str) -> list[tuple[Any, float]]:
    """Return new move objects of the mixture ``name`` (:data:`MOVE_SETS`).

    Parameters
    ----------
    name : str
        ``"de"`` (differential evolution 0.8 + snooker 0.2), ``"stretch"`` (emcee's
        default, Goodman & Weare 2010) or ``"de+stretch"`` (half each).

    Returns
    -------
    list of (emcee.moves.Move, float)

    Raises
    ------
    ValueError
        On an unknown name (the message lists the known ones).
    """
    if name not in MOVE_SETS:
        raise ValueError(f"unknown moves {name!r}; choose one of {sorted(MOVE_SETS)}")
    return MOVE_SETS[name]()
