"""Figures of the model-free amplitude curves (:mod:`bayesbeam.trials.amplitude`).

Built on :class:`matplotlib.figure.Figure` directly (object API, Agg canvas), as
:mod:`bayesbeam.report.plots`. The x axis is the mode-1 displacement amplitude in m
(``AmplitudeCurves.amplitude_m``), logarithmic; window estimates are drawn with error
bars of ±1 standard error, the amplitude-bin means on top.

* :func:`plot_mode1` (a: f1, b: ζ1), :func:`plot_mode2` (c: f2/f1 and ζ2,
  only where mode 2 is resolved), :func:`plot_residual_spectrogram` (d);
* :func:`write_amplitude_figures` writes all four as PNG files;
* ``extra`` curves ``{label: (amplitude_m, values)}`` are drawn over the data by
  :func:`overlay_curves`; :func:`model_extra` builds them from the curves of fitted
  models' predictions (``bayesbeam fit`` draws its model, ``bayesbeam diagnose`` the
  baseline and the final model).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import atomic_path

__all__ = [
    "FIGURES",
    "model_extra",
    "overlay_curves",
    "plot_mode1",
    "plot_mode1_in_time",
    "plot_mode2",
    "plot_residual_spectrogram",
    "write_amplitude_figures",
    "write_model_overlays",
]

#: File names written by :func:`write_amplitude_figures`, by panel key.
FIGURES = {
    "f1": "f1_vs_amplitude.png",
    "zeta1": "zeta1_vs_amplitude.png",
    "mode2": "mode2_vs_amplitude.png",
    "spectrogram": "residual_spectrogram.png",
    "time": "mode1_vs_time.png",
}

Extra = Mapping[str, tuple[Any, Any]]


def _figure(nrows: int = 1) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(7.5, 3.6 * nrows), layout="constrained")


def overlay_curves(ax: Any, extra: Extra | None) -> None:
    """Draw extra curves (e.g. a fitted model's predictions) over an amplitude plot.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        The axes (x: displacement amplitude in m).
    extra : mapping of str to (array_like, array_like), optional
        ``{label: (amplitude_m, values)}``; amplitudes in m, values in the units of
        the axes (Hz, dimensionless). Drawn as lines, sorted by amplitude.
    """
    for label, (a, v) in (extra or {}).items():
        a, v = np.asarray(a, dtype=float), np.asarray(v, dtype=float)
        ok = np.isfinite(a) & np.isfinite(v)  # windows where the mode was not resolved
        order = np.argsort(a[ok])
        ax.plot(a[ok][order], v[ok][order], "-", lw=1.5, label=label)


def model_extra(models: Mapping[str, Any]) -> dict[str, Any]:
    """Overlay curves for :func:`write_amplitude_figures` from models' amplitude curves.

    Parameters
    ----------
    models : mapping of str to AmplitudeCurves
        ``{label: curves}``, each from :func:`bayesbeam.trials.amplitude.amplitude_curves`
        run on a fitted model's noise-free prediction at the record's stamps (so the
        model is read by the same estimator as the data).

    Returns
    -------
    dict
        The ``extra`` argument of :func:`write_amplitude_figures`.
    """
    out: dict[str, Any] = {"f1": {}, "zeta1": {}, "mode2": {"ratio": {}, "zeta2": {}}}
    for label, c in models.items():
        a = c.amplitude_m
        out["f1"][label] = (a, c.frequency[:, 0])
        out["zeta1"][label] = (a, c.zeta[:, 0])
        if c.frequency.shape[1] > 1:
            out["mode2"]["ratio"][label] = (a, c.ratio[0])
            out["mode2"]["zeta2"][label] = (a, c.zeta[:, 1])
    return out


def _panel(ax: Any, curves: Any, x: np.ndarray, y: np.ndarray, se: np.ndarray,
           bx: np.ndarray, by: np.ndarray, bse: np.ndarray, ylabel: str,
           extra: Extra | None) -> None:
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0)
    ax.errorbar(x[ok], y[ok], yerr=np.where(np.isfinite(se[ok]), se[ok], 0.0), fmt="o",
                ms=3, lw=0.8, color="0.55", label="windows (±1 SE)")
    okb = np.isfinite(bx) & np.isfinite(by) & (bx > 0)
    if okb.any():
        ax.errorbar(bx[okb], by[okb], yerr=np.where(np.isfinite(bse[okb]), bse[okb], 0.0),
                    fmt="s", ms=5, color="C3", capsize=3, label="amplitude bins")
    overlay_curves(ax, extra)
    ax.set_xscale("log")
    tip = "" if curves.tip_factor == 1.0 else " (tip)"
    ax.set_xlabel(f"mode-1 displacement amplitude{tip} [m]")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)


def _bin_arrays(curves: Any, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    b = curves.bins
    return (np.array([x.amplitude_m for x in b]), np.array([getattr(x, name) for x in b]),
            np.array([getattr(x, name + "_se") for x in b]))


#: Mode-1 panels: attribute of the bins, column arrays of the windows, axis label, title.
_MODE1 = {"f1": ("f1", "frequency", "f1 [Hz]", "mode-1 frequency against amplitude"),
          "zeta1": ("zeta1", "zeta", "ζ1", "mode-1 damping ratio against amplitude")}


def plot_mode1(curves: Any, which: str, *, extra: Extra | None = None,
               title: str = "") -> Any:
    """Figure (a) or (b): mode-1 frequency or damping ratio against mode-1 amplitude.

    Parameters
    ----------
    curves : bayesbeam.trials.amplitude.AmplitudeCurves
        The window estimates.
    which : {"f1", "zeta1"}
        Frequency (Hz) or damping ratio.
    extra : mapping, optional
        Curves ``{label: (amplitude_m, values)}`` drawn over the data.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if which not in _MODE1:
        raise ValueError(f"which must be one of {sorted(_MODE1)}, got {which!r}")
    attr, column, label, default = _MODE1[which]
    fig = _figure()
    ax = fig.add_subplot()
    bx, by, bse = _bin_arrays(curves, attr)
    values, se = getattr(curves, column), getattr(curves, column + "_se")
    _panel(ax, curves, curves.amplitude_m, values[:, 0], se[:, 0], bx, by, bse, label, extra)
    ax.set_title(title or default)
    return fig


def plot_mode2(curves: Any, *, extra: Mapping[str, Extra] | None = None,
               title: str = "") -> Any | None:
    """Figure (c): f2/f1 and ζ2 against mode-1 amplitude, where mode 2 is resolved.

    Parameters
    ----------
    curves : bayesbeam.trials.amplitude.AmplitudeCurves
        The window estimates.
    extra : mapping, optional
        ``{"ratio": {label: (amplitude_m, f2/f1)}, "zeta2": {label: (amplitude_m, ζ2)}}``.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure or None
        None when no window resolves mode 2.
    """
    if curves.frequency.shape[1] < 2 or not np.isfinite(curves.frequency[:, 1]).any():
        return None
    extra = extra or {}
    fig = _figure(2)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ratio, ratio_se = curves.ratio
    bx, by, bse = _bin_arrays(curves, "ratio")
    _panel(ax1, curves, curves.amplitude_m, ratio, ratio_se, bx, by, bse, "f2 / f1",
           extra.get("ratio"))
    bx, by, bse = _bin_arrays(curves, "zeta2")
    _panel(ax2, curves, curves.amplitude_m, curves.zeta[:, 1], curves.zeta_se[:, 1],
           bx, by, bse, "ζ2", extra.get("zeta2"))
    ax1.set_title(title or "mode 2 against mode-1 amplitude")
    return fig


def plot_residual_spectrogram(curves: Any, *, title: str = "") -> Any:
    """Figure (d): spectrogram of the residual with the residual lines marked.

    Parameters
    ----------
    curves : bayesbeam.trials.amplitude.AmplitudeCurves
        The window estimates (``spectrogram``, ``lines``).
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _figure()
    ax = fig.add_subplot()
    f, t, amp = curves.spectrogram
    if amp.size:
        pos = amp[amp > 0]
        floor = float(np.percentile(pos, 5)) if pos.size else 1e-300
        mesh = ax.pcolormesh(t, f, 20 * np.log10(np.maximum(amp, floor)), shading="auto",
                             cmap="viridis")
        fig.colorbar(mesh, ax=ax, label="residual amplitude [dB re 1 SI unit]")
        ax.set_ylim(0, float(f[-1]))
    for line in curves.lines:
        ax.axhline(line.frequency, color="w", lw=0.8, ls="--")
        ax.annotate(line.label, (1.0, line.frequency), xycoords=("axes fraction", "data"),
                    xytext=(3, 0), textcoords="offset points", fontsize=7, va="center")
    ax.set_yscale("symlog", linthresh=max(1.0, 2 * float(np.nanmax(curves.frequency[:, 0]))))
    ax.set_xlabel("time [s]")
    ax.set_ylabel("frequency [Hz]")
    ax.set_title(title or "residual of the windowed modal fit")
    return fig


def plot_mode1_in_time(curves: Any, *, change: Any = None, title: str = "") -> Any:
    """f1 and ζ1 window by window against time, a change of state marked.

    Parameters
    ----------
    curves : bayesbeam.trials.amplitude.AmplitudeCurves
    change : bayesbeam.trials.state_change.StateChange, optional
        Drawn as a shaded band ``time_s ± time_halfwidth_s`` with the levels before and
        after, when ``change.found``.
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _figure(2)
    axes = fig.subplots(2, 1, sharex=True)
    t = np.asarray(curves.centre, dtype=float)
    for ax, (y, se, label, before, after) in zip(axes, (
            (curves.frequency[:, 0], curves.frequency_se[:, 0], "f1 [Hz]",
             "frequency_before_hz", "frequency_after_hz"),
            (curves.zeta[:, 0], curves.zeta_se[:, 0], "ζ1", "zeta_before", "zeta_after")),
            strict=True):
        ok = np.isfinite(y)
        ax.errorbar(t[ok], y[ok], yerr=np.where(np.isfinite(se[ok]), se[ok], 0.0), fmt="o",
                    ms=3, lw=0.8, color="0.45", label="windows (±1 SE)")
        if change is not None and change.found:
            lo = change.time_s - change.time_halfwidth_s
            hi = change.time_s + change.time_halfwidth_s
            ax.axvspan(lo, hi, color="C3", alpha=0.15, label="change of state")
            ax.hlines([change.levels[before]], *change.levels["before_s"], colors="C0",
                      lw=1.5, label="level before (its windows)")
            ax.hlines([change.levels[after]], *change.levels["after_s"], colors="C1", lw=1.5,
                      label="level after (its windows)")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    axes[-1].set_xlabel("time [s]")
    state = ("" if change is None else
             "; change of state" if change.found else "; no change of state")
    axes[0].set_title(f"{title}mode 1 in time{state}")
    return fig


def write_amplitude_figures(curves: Any, outdir: str | Path, *,
                            extra: Mapping[str, Any] | None = None, title: str = "",
                            dpi: int = 110, change: Any = None) -> list[Path]:
    """Write figures (a)-(d) as PNG files into ``outdir`` (names in :data:`FIGURES`).

    Parameters
    ----------
    curves : bayesbeam.trials.amplitude.AmplitudeCurves
        The window estimates.
    outdir : str or Path
        Folder (created if needed).
    extra : mapping, optional
        Model curves by panel: ``{"f1": {...}, "zeta1": {...}, "mode2": {"ratio": {...},
        "zeta2": {...}}}``, each ``{label: (amplitude_m, values)}``.
    title : str
        Prefix of the figure titles (e.g. the trial name).
    dpi : int
        Resolution.
    change : bayesbeam.trials.state_change.StateChange, optional
        A change of state to mark on the f1, ζ1-in-time figure.

    Returns
    -------
    list of Path
        The files written (no mode-2 figure when mode 2 is never resolved).
    """
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    extra = extra or {}
    pre = f"{title}: " if title else ""
    figs = {
        "f1": plot_mode1(curves, "f1", extra=extra.get("f1"),
                         title=pre + _MODE1["f1"][3]),
        "zeta1": plot_mode1(curves, "zeta1", extra=extra.get("zeta1"),
                            title=pre + _MODE1["zeta1"][3]),
        "mode2": plot_mode2(curves, extra=extra.get("mode2"),
                            title=pre + "mode 2 against mode-1 amplitude"),
        "spectrogram": plot_residual_spectrogram(
            curves, title=pre + "residual of the windowed modal fit"),
        "time": plot_mode1_in_time(curves, change=change, title=pre),
    }
    paths = []
    for key, fig in figs.items():
        if fig is None:
            continue
        path = out / FIGURES[key]
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
        paths.append(path)
    return paths


def write_model_overlays(trial: Any, predictions: Mapping[str, Any], outdir: str | Path, *,
                         say: Any = None) -> list[Path]:
    """Amplitude figures of a record with fitted models' curves drawn over the data's.

    The data's curves and each model's come from the same estimator
    (:func:`bayesbeam.trials.amplitude.amplitude_curves`, two modes), the model's on its
    noise-free prediction at the record's stamps, so what differs is what the model
    gets wrong (a linear model's f1 and ζ1 are flat in amplitude).

    Parameters
    ----------
    trial : bayesbeam.trials.trial.Trial
        The record as fitted.
    predictions : mapping of str to ndarray, shape (T,)
        ``{label: signal}``, e.g. the posterior-median prediction of each model.
    outdir : str or Path
        Folder of the figures (names in :data:`FIGURES`).
    say : callable, optional
        Receives a line when the curves cannot be drawn (e.g. a record shorter than
        three windows); nothing is written then.

    Returns
    -------
    list of Path
        The files written.
    """
    from bayesbeam.trials.amplitude import amplitude_curves, tip_factor
    from bayesbeam.trials.modal_id import SignatureError

    kw = {"n_modes": 2, "quantity": trial.quantity, "tip_factor": tip_factor(trial.beam)}
    try:
        data = amplitude_curves(trial.times, trial.values, **kw)
        f1 = data.settings["start_frequencies_hz"][0]
        models = {label: amplitude_curves(trial.times, y, f1=f1, **kw)
                  for label, y in predictions.items()}
    except SignatureError as err:
        if say is not None:
            say(f"amplitude curves not drawn: {err}")
        return []
    return write_amplitude_figures(data, outdir, extra=model_extra(models), title=trial.name)
