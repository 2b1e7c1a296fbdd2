"""Plots of a :class:`~bayesbeam.inference.results.FitResult`: corner and trace.

The record's own methods (``FitResult.plot_corner``, ``FitResult.plot_trace``) call these.
Figures are bare matplotlib ``Figure`` objects rendered with the Agg canvas, so that
pyplot's global state and backend stay untouched; files are written atomically.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import INTERVAL_QUANTILES as _QUANTILES
from bayesbeam._util import atomic_path

__all__ = ["plot_corner", "plot_trace"]


class _CornerNotes(logging.Filter):
    """Count corner's "Too few points to create valid contours" warnings, not print them.

    corner reports a 2-D panel whose samples are too concentrated for its density
    levels through the root logger, once per panel; the figure says so instead (a
    note on it), so that a fit's output is not a screen of logging lines.
    """

    MESSAGE = "Too few points to create valid contours"

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def filter(self, record: logging.LogRecord) -> bool:  # noqa: D102
        if record.getMessage() == self.MESSAGE:
            self.count += 1
            return False
        return True

    def __enter__(self) -> _CornerNotes:
        logging.getLogger().addFilter(self)
        return self

    def __exit__(self, *exc: object) -> None:
        logging.getLogger().removeFilter(self)


def plot_corner(result: Any, path: str | Path, *, truths: Any = None, dpi: int = 120,
                names: Any = None) -> Path:
    """Corner plot of the physical posterior (corner package) with 5/50/95 % marks.

    Parameters
    ----------
    result : bayesbeam.inference.results.FitResult
    path : str or pathlib.Path
        Image file; the format follows the suffix (``.png``, ``.pdf``, ...).
    truths : array_like, optional
        Reference values (e.g. the truth of a synthetic trial), one per plotted
        parameter; ``None`` entries are skipped.
    dpi : int, default 120
    names : sequence of str, optional
        Plot only these sampled parameters, in this order (e.g. a joint fit's shared
        and population parameters); default all. One name gives a histogram with
        the 90 % interval in its title.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ValueError
        If ``names`` holds a name that is not sampled.
    """
    import corner
    from matplotlib.figure import Figure

    from bayesbeam._util import fmt_interval

    names = list(result.names) if names is None else list(names)
    unknown = [n for n in names if n not in result.names]
    if unknown or not names:
        raise ValueError(f"cannot plot {unknown or 'no parameter'}: the sampled "
                         f"parameters are {list(result.names)}")
    cols = [result.names.index(n) for n in names]
    # A bare Figure renders with the Agg canvas and leaves pyplot's global
    # state and backend untouched (no import-time or global side effects).
    nd = len(cols)
    fig = Figure(figsize=(2.2 * nd + 1, 2.2 * nd + 1))
    flat = result.theta_samples().reshape(-1, result.chain.ndim)[:, cols]
    if nd == 1:  # corner draws a bare histogram without its interval for one column
        ax = fig.subplots()
        ax.hist(flat[:, 0], bins=40, color="0.4")
        q = np.quantile(flat[:, 0], list(_QUANTILES.values()))
        for v in q:
            ax.axvline(v, color="k", ls="--", lw=0.8)
        if truths is not None and truths[0] is not None:
            ax.axvline(float(truths[0]), color="C0", lw=1.2)
        ax.set_xlabel(names[0])
        mid, lo, hi = fmt_interval(q[1], q[0], q[2])
        ax.set_title(f"{names[0]} = {mid} [{lo}, {hi}] (90 %)", fontsize=9)
    else:
        # A positive parameter spread over more than a decade (a ridge the data do
        # not close: E and a clamp spring, a damping split) on a log axis: on a
        # linear one its samples crowd into one bin and corner draws no contour.
        lo, hi = np.quantile(flat, [0.05, 0.95], axis=0)
        wide = (lo > 0) & (hi > 10 * lo)
        with _CornerNotes() as notes:
            corner.corner(
                flat,
                labels=[f"{n} (log axis)" if w else n for n, w in zip(names, wide,
                                                                      strict=True)],
                quantiles=list(_QUANTILES.values()),
                show_titles=True,
                title_fmt=".3g",
                truths=None if truths is None else list(truths),
                axes_scale=["log" if w else "linear" for w in wide],
                fig=fig,
            )
        if notes.count:
            fig.text(0.99, 0.01, f"{notes.count} panel(s) without contours: samples too "
                     "concentrated for density levels", ha="right", fontsize=7)
    fig.suptitle(f"{result.model}: posterior ({flat.shape[0]} samples)")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    return path

def plot_trace(result: Any, path: str | Path, *, dpi: int = 120,
               max_walkers: int = 64) -> Path:
    """Trace plot: walkers' physical values against step, and marginal histograms.

    Parameters
    ----------
    result : bayesbeam.inference.results.FitResult
    path : str or pathlib.Path
        Image file.
    dpi : int, default 120
    max_walkers : int, default 64
        Draw at most this many walkers (all are used for the histograms).

    Returns
    -------
    pathlib.Path
    """
    from matplotlib.figure import Figure

    c = result.chain
    th = result.theta_samples()
    steps = c.burn_in + c.thin * np.arange(c.nsteps)
    fig = Figure(figsize=(10, 1.9 * c.ndim + 0.8), layout="constrained")
    axes = fig.subplots(c.ndim, 2, squeeze=False, width_ratios=[4, 1])
    for j, name in enumerate(result.names):
        ax, hx = axes[j]
        ax.plot(steps, th[:, :max_walkers, j], lw=0.4, alpha=0.4, color="k")
        ax.set_ylabel(name)
        hx.hist(th[:, :, j].ravel(), bins=50, orientation="horizontal", color="0.4")
        hx.set_ylim(ax.get_ylim())
        hx.tick_params(labelleft=False)
    axes[-1, 0].set_xlabel("step (after burn-in)")
    fig.suptitle(
        f"{result.model}: traces (tau_max {c.tau_max:.1f}, ESS min {c.ess_min:.0f}, "
        f"R-hat max {c.rhat_max:.3f})"
    )
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    return path
