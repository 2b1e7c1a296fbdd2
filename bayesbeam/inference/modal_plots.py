"""The ζ-vs-f picture: damping ratio against natural frequency, per mode and model.

Damping laws separate by how the damping ratio ``ζ_k`` of mode k varies with its natural
frequency ``f_k`` (physics.md §2): viscous damping gives ``ζ ∝ 1/f``, Kelvin–Voigt
``ζ ∝ f``, spatial hysteresis lies between (a narrow kernel acts like Kelvin–Voigt). On
log-log axes these are straight lines of slope −1 and +1; :func:`plot_zeta_vs_f` draws
both through the first mode as thin dotted references, the posterior medians of
:class:`bayesbeam.inference.modal.ModalPosterior` with their 5–95 % intervals on both
axes (one colour per model), the draws themselves as faint dots, and, when the record
gave them, the data's own estimates (:func:`bayesbeam.inference.modal.data_modes`).

The figure is built on :class:`matplotlib.figure.Figure` (object API, Agg canvas), as in
:mod:`bayesbeam.report.plots`; it lives here, beside the record it draws, so that
:class:`bayesbeam.comparison.compare.Comparison` (a layer below ``report``) can write it.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import atomic_path
from bayesbeam.inference.modal import DataModes, ModalPosterior

__all__ = ["plot_zeta_vs_f", "zeta_vs_f_figure"]

_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">")


def _records(records: Any) -> list[ModalPosterior]:
    if isinstance(records, ModalPosterior):
        return [records]
    if isinstance(records, Mapping):
        return list(records.values())
    if isinstance(records, Sequence):
        return list(records)
    raise TypeError(
        "records must be a ModalPosterior, a sequence of them or a mapping name -> record, "
        f"got {type(records).__name__}"
    )


def _positive_errors(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Asymmetric error bars ``[x - lo, hi - x]`` kept above zero for log axes."""
    low = np.minimum(x - lo, 0.999 * x)  # a lower end at or below 0 is cut (log scale)
    return np.vstack([np.maximum(low, 0.0), np.maximum(hi - x, 0.0)])


def zeta_vs_f_figure(
    records: ModalPosterior | Sequence[ModalPosterior] | Mapping[str, ModalPosterior],
    *,
    data: DataModes | bool | None = True,
    title: str | None = None,
) -> Any:
    """Build the ζ-vs-f figure (see the module docstring) without writing it.

    Parameters
    ----------
    records : ModalPosterior, sequence or mapping of them
        One per model; records without a modal posterior are named in the caption.
    data : DataModes, bool or None, default True
        The data's estimates to overlay: ``True`` takes the first record's
        :attr:`~bayesbeam.inference.modal.ModalPosterior.data`; ``False``/``None``: none.
    title : str, optional
        Figure title (default: the models).

    Returns
    -------
    matplotlib.figure.Figure or None
        None when no record has a modal posterior. The posterior intervals are
        :class:`~matplotlib.container.ErrorbarContainer` objects labelled with the model
        name; the data's is labelled ``"data"``.
    """
    from matplotlib.figure import Figure

    recs = _records(records)
    avail = [r for r in recs if r.available]
    if not avail:
        return None
    if data is True:
        data = next((r.data for r in avail if r.data is not None), None)
    elif data is False:
        data = None

    fig = Figure(figsize=(8.0, 5.8), layout="constrained")
    ax = fig.subplots()
    ax.set_xscale("log")
    ax.set_yscale("log")
    xs: list[float] = []
    for j, rec in enumerate(avail):
        color, marker = f"C{j % 10}", _MARKERS[j % len(_MARKERS)]
        # The draws themselves: the correlation of f_k and ζ_k that intervals hide.
        ax.scatter(rec.frequency_hz.ravel(), rec.damping_ratio.ravel(), s=4, alpha=0.12,
                   color=color, linewidths=0, rasterized=True)
        rows = rec.summary()
        f = np.array([r["frequency_hz"]["q50"] for r in rows])
        z = np.array([r["damping_ratio"]["q50"] for r in rows])
        flo = np.array([r["frequency_hz"]["q05"] for r in rows])
        fhi = np.array([r["frequency_hz"]["q95"] for r in rows])
        zlo = np.array([r["damping_ratio"]["q05"] for r in rows])
        zhi = np.array([r["damping_ratio"]["q95"] for r in rows])
        label = rec.model + (" (linear part)" if rec.source != "model" else "")
        ax.errorbar(f, z, xerr=_positive_errors(f, flo, fhi), yerr=_positive_errors(z, zlo, zhi),
                    fmt=marker, color=color, ms=6, capsize=3, lw=1.2, label=label)
        if j == 0:
            for k, (fk, zk) in enumerate(zip(f, z, strict=True)):
                ax.annotate(str(k + 1), (fk, zk), textcoords="offset points", xytext=(6, 6),
                            fontsize="small", color="0.2")
        xs += [*flo.tolist(), *fhi.tolist()]
    anchor, anchor_from = None, ""
    if isinstance(data, DataModes):
        fd, zd = data.frequency_hz, data.damping_ratio
        m = np.isfinite(fd) & np.isfinite(zd) & (fd > 0) & (zd > 0)
        if np.any(m):
            fi, zi = data.frequency_90[m], data.damping_90[m]
            ax.errorbar(fd[m], zd[m], xerr=_positive_errors(fd[m], fi[:, 0], fi[:, 1]),
                        yerr=_positive_errors(zd[m], zi[:, 0], zi[:, 1]), fmt="s", mfc="none",
                        color="k", ms=8, capsize=3, lw=1.0, label="data")
            xs += [*fi[:, 0].tolist(), *fi[:, 1].tolist()]
            if m[0]:
                anchor, anchor_from = (float(fd[0]), float(zd[0])), "the data's mode 1"
    if anchor is None:
        r0 = avail[0].summary()[0]
        anchor = (r0["frequency_hz"]["q50"], r0["damping_ratio"]["q50"])
        anchor_from = f"mode 1 of {avail[0].model}"
    xv = np.array([x for x in xs if math.isfinite(x) and x > 0])
    x0, x1 = float(xv.min()) / 1.4, float(xv.max()) * 1.4
    grid = np.geomspace(x0, x1, 50)
    f1, z1 = anchor
    # Reference laws through the first mode (physics.md §2): ζ = ζ1 (f/f1)^∓1.
    ax.plot(grid, z1 * f1 / grid, ls=":", lw=0.9, color="0.25",
            label="ζ ∝ 1/f (viscous)")
    ax.plot(grid, z1 * grid / f1, ls=":", lw=0.9, color="0.55",
            label="ζ ∝ f (Kelvin–Voigt)")
    ax.set_xlim(x0, x1)
    # Keep the reference lines from setting the vertical range: the points decide it.
    zs = [v for r in avail for v in r.damping_ratio.ravel().tolist()]
    if isinstance(data, DataModes):
        zs += [v for v in data.damping_ratio.tolist() if math.isfinite(v) and v > 0]
    zv = np.array([v for v in zs if math.isfinite(v) and v > 0] + [z1])
    ax.set_ylim(float(zv.min()) / 3, float(zv.max()) * 3)
    ax.set_xlabel("natural frequency f_k [Hz]")
    ax.set_ylabel("damping ratio ζ_k [-]")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(loc="best", fontsize="small")
    ax.set_title(title or "damping ratio against frequency: " + ", ".join(r.model for r in avail))
    cap = [f"medians with 5-95 % posterior intervals on both axes; dots: the draws; "
           f"dotted: slopes -1 and +1 through {anchor_from}"]
    if isinstance(data, DataModes):
        cap.append("data: damped-sinusoid fit of the record, 90 % normal intervals")
    for r in recs:
        if not r.available:
            cap.append(f"{r.model}: no modal posterior ({r.reason})")
        elif r.n_invalid or r.n_overdamped:
            cap.append(f"{r.model}: {r.n_draws} of {r.n_requested} draws "
                       f"({r.n_overdamped} overdamped, {r.n_invalid} invalid left out)")
    # supxlabel: the constrained layout makes room for it (a fig.text would overlap).
    fig.supxlabel(textwrap.fill("; ".join(cap), 150), fontsize="x-small", x=0.01, ha="left")
    return fig


def plot_zeta_vs_f(
    records: ModalPosterior | Sequence[ModalPosterior] | Mapping[str, ModalPosterior],
    path: str | Path,
    *,
    data: DataModes | bool | None = True,
    title: str | None = None,
    dpi: int = 120,
) -> Path | None:
    """Write the ζ-vs-f figure (log-log; module docstring) to ``path``.

    Parameters
    ----------
    records : ModalPosterior, sequence or mapping of them
        One per model.
    path : str or pathlib.Path
        Image file; the format follows the suffix (``.png``, ``.pdf``, ...).
    data : DataModes, bool or None, default True
        See :func:`zeta_vs_f_figure`.
    title : str, optional
    dpi : int, default 120

    Returns
    -------
    pathlib.Path or None
        The file, or None (nothing written) when no record has a modal posterior; the
        records' ``reason`` says why.
    """
    fig = zeta_vs_f_figure(records, data=data, title=title)
    if fig is None:
        return None
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    return path
