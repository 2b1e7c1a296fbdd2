"""The ζ-vs-f figure: written, not blank, and its intervals are the record's.

The records are built from chosen draws (no fit): the plotted 5-95 % intervals of mode 1
must be the record's summary, the reference lines must have slopes -1 (viscous) and +1
(Kelvin–Voigt) on the log-log axes through the first mode.
"""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.container import ErrorbarContainer
from matplotlib.image import imread

from bayesbeam.inference.modal import DataModes, ModalPosterior
from bayesbeam.inference.modal_plots import plot_zeta_vs_f, zeta_vs_f_figure

F0 = np.array([11.4, 71.2, 199.0])


def _record(model: str, slope: float, seed: int, n: int = 300) -> ModalPosterior:
    """Draws around ζ = 0.01 (f/f1)^slope with a few per cent scatter."""
    rng = np.random.default_rng(seed)
    f = F0 * np.exp(0.02 * rng.standard_normal((n, 1)))
    z = 0.01 * (f / F0[0]) ** slope * np.exp(0.1 * rng.standard_normal((n, 3)))
    return ModalPosterior(model=model, frequency_hz=f, damping_ratio=z,
                          draw_index=np.arange(n), n_requested=n + 5, n_overdamped=5)


def _data() -> DataModes:
    return DataModes(frequency_hz=F0 * 1.001, frequency_se_hz=F0 * 1e-4,
                     damping_ratio=np.array([0.0101, 0.0016, np.nan]),
                     damping_ratio_se=np.array([2e-4, 1e-4, np.nan]))


def _container(fig, label: str) -> ErrorbarContainer:
    found = [c for c in fig.axes[0].containers
             if isinstance(c, ErrorbarContainer) and c.get_label() == label]
    assert len(found) == 1, [c.get_label() for c in fig.axes[0].containers]
    return found[0]


def _bars(container: ErrorbarContainer) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal (x-error) and vertical (y-error) bar segments, each (n, 2, 2)."""
    segs = np.concatenate([np.asarray(lc.get_segments()) for lc in container.lines[2]])
    horiz = segs[np.isclose(segs[:, 0, 1], segs[:, 1, 1], rtol=0, atol=0)]
    vert = segs[np.isclose(segs[:, 0, 0], segs[:, 1, 0], rtol=0, atol=0)]
    return horiz, vert


def test_png_is_written_and_not_blank(tmp_path):
    rec = _record("viscous", -1.0, 0)
    path = plot_zeta_vs_f(rec, tmp_path / "zeta_vs_f.png", title="t")
    assert path == tmp_path / "zeta_vs_f.png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = imread(path)[..., :3]
    assert img.shape[0] > 300 and img.shape[1] > 400
    # Not blank: a good share of the pixels is not white, and there is colour (markers).
    assert np.mean(np.any(img < 0.95, axis=-1)) > 0.02
    assert np.any(np.ptp(img, axis=-1) > 0.3)


def test_mode_1_interval_is_the_summary():
    rec = _record("viscous", -1.0, 1)
    fig = zeta_vs_f_figure(rec, data=False)
    row = rec.summary()[0]
    f, z = row["frequency_hz"], row["damping_ratio"]
    c = _container(fig, "viscous")
    x, y = c.lines[0].get_data()
    assert x[0] == pytest.approx(f["q50"], rel=1e-12) and y[0] == pytest.approx(z["q50"],
                                                                                 rel=1e-12)
    horiz, vert = _bars(c)
    h1 = horiz[np.argmin(np.abs(horiz[:, 0, 1] - z["q50"]))]  # mode 1's frequency bar
    np.testing.assert_allclose(sorted(h1[:, 0]), [f["q05"], f["q95"]], rtol=1e-12)
    v1 = vert[np.argmin(np.abs(vert[:, 0, 0] - f["q50"]))]  # mode 1's damping bar
    np.testing.assert_allclose(sorted(v1[:, 1]), [z["q05"], z["q95"]], rtol=1e-12)
    assert fig.axes[0].get_xscale() == "log" and fig.axes[0].get_yscale() == "log"


def test_reference_slopes_through_the_first_mode_and_data_overlay():
    rec = _record("kv", 1.0, 2)
    data = _data()
    fig = zeta_vs_f_figure([rec, _record("viscous", -1.0, 3)], data=data)
    ax = fig.axes[0]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    for label, slope in (("ζ ∝ 1/f (viscous)", -1.0), ("ζ ∝ f (Kelvin–Voigt)", 1.0)):
        x, y = (np.asarray(a, dtype=float) for a in lines[label].get_data())
        assert lines[label].get_linestyle() == ":"
        s = np.diff(np.log(y)) / np.diff(np.log(x))
        np.testing.assert_allclose(s, slope, rtol=1e-9)
        # through the data's mode 1 (the model-free anchor)
        np.testing.assert_allclose(np.interp(np.log(data.frequency_hz[0]), np.log(x),
                                             np.log(y)), np.log(data.damping_ratio[0]),
                                   atol=1e-9)
    # The data overlay: the two measured modes, with their 90 % normal intervals.
    d = _container(fig, "data")
    x, y = d.lines[0].get_data()
    np.testing.assert_allclose(x, data.frequency_hz[:2])
    horiz, _ = _bars(d)
    np.testing.assert_allclose(np.sort(horiz[0][:, 0]), data.frequency_90[0], rtol=1e-12)
    # One colour per model.
    colours = {_container(fig, m).lines[0].get_color() for m in ("kv", "viscous")}
    assert len(colours) == 2


def test_nothing_written_without_a_modal_posterior(tmp_path):
    empty = ModalPosterior(model="viscous", frequency_hz=np.empty((0, 0)),
                           damping_ratio=np.empty((0, 0)), draw_index=np.empty(0, dtype=int),
                           n_requested=4, n_overdamped=4, reason="no draw gives 2 underdamped "
                           "modes")
    assert plot_zeta_vs_f(empty, tmp_path / "z.png") is None
    assert not (tmp_path / "z.png").exists()
    # Beside an available record it is named in the caption, not drawn.
    fig = zeta_vs_f_figure({"viscous": empty, "kv": _record("kv", 1.0, 4)})
    texts = " ".join(" ".join(t.get_text() for t in fig.texts).split())  # unwrapped
    assert "viscous: no modal posterior (no draw gives 2 underdamped modes)" in texts
    assert [c.get_label() for c in fig.axes[0].containers] == ["kv"]
    with pytest.raises(TypeError, match="records must be"):
        zeta_vs_f_figure(3.0)
