"""Compiled-on-demand kernel of the AR(1) log-likelihood of :mod:`bayesbeam.stats.likelihood`.

The sum of squared, weighted innovations of :func:`bayesbeam.stats.likelihood.ar1_loglik`,
one parameter set at a time, written as plain Python on numpy arrays so that numba can
compile it (:func:`bayesbeam._util.compiled_kernel`, done lazily by
:mod:`bayesbeam.stats.likelihood`) and so that it runs, slowly, without numba (the tests
check its logic that way). Nothing here imports numba.

Why a kernel: on a whole record (14,118 samples with gaps, so a lag table of a few
distinct steps) the batched numpy route gathers each set's lag correlation and weight
per sample and makes five temporaries the size of the batch: 547 µs per set, against
22 µs for the i.i.d. likelihood of the same residuals, and 20-45 % of a whole-record
model's log density (measured on Al 60 cm #1). Here it is one pass over the residuals.
"""

from __future__ import annotations

import numpy as np


def _ar1_sum_py(r, phi, w, index):
    """Return ``Σ_t w[b, k_t] (r[b, t] - phi[b, k_t] r[b, t-1])²`` for each set ``b``.

    Parameters
    ----------
    r : ndarray, shape (B, T)
        Residuals.
    phi, w : ndarray, shape (B, K)
        Lag correlation and innovation weight ``1 / (1 - phi²)`` of each distinct step.
    index : ndarray of int64, shape (T - 1,)
        ``k_t``: the distinct step between samples ``t - 1`` and ``t``.

    Returns
    -------
    ndarray, shape (B,)
    """
    B, T = r.shape
    out = np.empty(B)
    for b in range(B):
        q = 0.0
        for t in range(1, T):
            k = index[t - 1]
            e = r[b, t] - phi[b, k] * r[b, t - 1]
            q += w[b, k] * e * e
        out[b] = q
    return out
