"""Ensemble proposal moves that emcee's release does not provide correctly.

* :class:`SnookerMove` — the differential-evolution snooker update (ter Braak & Vrugt
  2008, Stat. Comput. 18, 435, eqs. 4-5). emcee 3.1.6's ``DESnookerMove`` (its latest
  release) normalises the projection direction by the square root of the distance and
  halves the Jacobian term, so that its chain does not have the target as its
  stationary law (fixed upstream in emcee pull request 531, not released):
  ``tests/stats/test_moves.py`` shows the package's mixture reproducing a closed-form
  posterior where the released move's is ~2x off in a scale parameter's median.

A move is a small object with one job, as emcee's own: it proposes and returns the
log-ratio of the proposal densities; the ensemble sampler accepts or rejects.
"""

from __future__ import annotations

import numpy as np
from emcee.moves.red_blue import RedBlueMove

__all__ = ["SnookerMove"]


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
