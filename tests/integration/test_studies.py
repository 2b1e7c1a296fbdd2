"""Shipped data (studies/make_data.py), the source-replication study and the notebook."""

from __future__ import annotations

import hashlib
import importlib.util
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np
import pytest

import bayesbeam
from bayesbeam.trials.io import read_trial

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
STUDIES = ROOT / "studies"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"_study_{name}", STUDIES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def make_data():
    return _load("make_data")


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_make_data_reproduces_the_shipped_files(make_data, tmp_path):
    # TOML files (beam, truth, settings) come back byte for byte. The CSV values (mm,
    # 6 decimals) differ between numpy/scipy/LAPACK builds in the last one or two
    # written digits (seen: 2e-6 mm with numpy 2.5 / scipy 1.18 against the builds that
    # wrote data/): each value must agree to 1e-3 of the white noise sd in truth.toml
    # (8e-6 mm), invisible to any fit; header and time column exactly.
    atol_mm = 1e-3 * tomllib.loads((DATA / "truth.toml").read_text())["noise"]["white_sd"] * 1e3
    written = make_data.main(tmp_path, verbose=False)
    assert len(written) == 31  # 15 TOML + 15 CSV + truth.toml
    for p in written:
        ref = DATA / p.name
        if p.suffix != ".csv":
            assert _sha(p) == _sha(ref), f"{p.name} differs from data/{p.name}"
            continue
        new, old = p.read_text().splitlines(), ref.read_text().splitlines()
        assert new[0] == old[0] and len(new) == len(old), p.name
        a = np.loadtxt(p, delimiter=",", skiprows=1)
        b = np.loadtxt(ref, delimiter=",", skiprows=1)
        np.testing.assert_array_equal(a[:, 0], b[:, 0], err_msg=p.name)
        np.testing.assert_allclose(a[:, 1], b[:, 1], rtol=0, atol=atol_mm, err_msg=p.name)


def test_shipped_data_is_small_and_licensed():
    files = [p for p in DATA.iterdir() if p.is_file()]
    assert sum(p.stat().st_size for p in files) < 1_000_000
    readme = (DATA / "README.md").read_text(encoding="utf-8")
    assert "CC0" in readme and "studies/make_data.py" in readme


def test_trials_describe_what_a_user_knows(make_data):
    truth = tomllib.loads((DATA / "truth.toml").read_text())
    for spec in make_data.BEAMS:
        for j in range(5):
            path = DATA / f"{spec.name}-trial{j + 1}.toml"
            doc = tomllib.loads(path.read_text())
            # Hidden truths are not in the trial description.
            for hidden in ("E", "root_spring"):
                assert hidden not in doc["beam"], (path.name, hidden)
            t = read_trial(path)
            assert len(t) == 1280 and t.is_uniform and t.dt == pytest.approx(1 / 256, rel=1e-12)
            b = t.beam
            assert (b.length, b.width, b.thickness) == (0.3048, 0.127, spec.thickness)
            assert b.beam_mass == pytest.approx(spec.mass, rel=1e-12)
            assert b.tip_mass == 0.0004 and len(b.segments) == 1
            assert b.root_spring is None and b.E is None
            # The nominal release deflection is the true one to the nearest mm.
            w_true = truth[spec.name]["tip_deflections"][j]
            assert abs(t.initial["tip_deflection"] - w_true) <= 0.0005 + 1e-12
            # The record starts at the release deflection (plus noise of ~11 µm sd), less
            # the share of the modes above the vibrometer's 100 Hz band (2 % at most here:
            # mode 2 of beam 3; a mode's share of a tip-load deflection falls as 1/ω²).
            assert t.bandwidth == pytest.approx(100.0)
            assert abs(t.values[0] - w_true) < 6e-5 + 0.025 * w_true


def test_first_frequency_in_the_data_matches_the_generating_beam(make_data):
    # Independent check of the generator: the spectral peak of every record (numpy FFT,
    # 64x zero padding, Hann window) against the first natural frequency of the true beam.
    # Tolerance 0.03 Hz: padded bin 0.003 Hz; the damped peak of a decaying record sits
    # within ~zeta^2 f1 (< 1e-3 Hz) of the natural frequency; Hann leakage from mode 2
    # (2.5 % amplitude, > 30 Hz away) shifts it by far less.
    truth = tomllib.loads((DATA / "truth.toml").read_text())
    for spec in make_data.BEAMS:
        f1 = truth[spec.name]["frequencies_hz"][0]
        for j in range(5):
            t = read_trial(DATA / f"{spec.name}-trial{j + 1}.toml")
            y = (t.values - t.values.mean()) * np.hanning(len(t))
            n = 64 * len(t)
            spec_abs = np.abs(np.fft.rfft(y, n))
            f = np.fft.rfftfreq(n, t.dt)
            band = (f > 2) & (f < 40)
            peak = f[band][np.argmax(spec_abs[band])]
            assert abs(peak - f1) < 0.03, (spec.name, j, peak, f1)


def test_truth_matches_the_generator(make_data):
    truth = tomllib.loads((DATA / "truth.toml").read_text())
    for spec in make_data.BEAMS:
        t = truth[spec.name]
        assert t["E"] == spec.E and t["root_spring"] == spec.root_spring
        assert t["damping"] == spec.damping and t["model"] == spec.model
        # Clamp compliance lowers f1 by "several percent" (physics.md §3).
        assert -0.06 < t["f1_shift_from_clamp"] < -0.02
    assert truth["noise"]["ar1_rho"] == make_data.NOISE_AR_RHO


@pytest.mark.slow
def test_source_replication_runs_at_a_small_size(tmp_path):
    study = _load("source_replication")
    res = study.main(small=True, outdir=tmp_path, progress=False)
    md = res["markdown"]
    assert res["path"].is_file() and (tmp_path / "report.html").is_file()
    assert "Conclusions compared with the source" in md and "beam2-trial1" in md
    assert "| viscous+kv |" in md
    rows = res["replication"].rows
    assert {r["model"] for r in rows} == {"viscous", "viscous+kv"}
    assert all(np.isfinite(r["log_z"]) for r in rows)


def _notebook_text(nb) -> str:
    """Every code cell's outputs as one text: streams, plain-text and HTML results, errors."""
    parts = []
    for c in nb.cells:
        for o in c.get("outputs", []):
            parts.append(o.get("text", ""))
            data = o.get("data", {})
            parts += [data.get("text/plain", ""), data.get("text/html", ""),
                      data.get("text/markdown", "")]
            parts += [o.get("evalue", "")]
    return "\n".join(parts)


def test_committed_notebook_keeps_its_outputs():
    # The notebook is rendered in the repository: every code cell ran, none failed, the
    # report was written, and no machine's paths (this checkout, the temporary folder,
    # the interpreter) were written into it.
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.read(STUDIES / "model_comparison.ipynb", as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.outputs for c in code)
    counts = [c.execution_count for c in code]
    assert counts == list(range(1, len(code) + 1)), "executed in order, in one kernel"
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]
    assert any(o.get("output_type") == "display_data" and "image/png" in o.get("data", {})
               for c in code for o in c.outputs)
    text = _notebook_text(nb)
    assert "report.html" in text and "beam1-trial1.toml" in text
    for local in (str(ROOT), tempfile.gettempdir(), sys.prefix, str(Path.home())):
        assert local not in text, f"the notebook's outputs name a local path ({local})"
    # Kept small: the figures are the bulk; far under the data folder's size.
    assert (STUDIES / "model_comparison.ipynb").stat().st_size < 400_000


@pytest.mark.slow
def test_notebook_executes_with_the_venv_kernel(tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(STUDIES / "model_comparison.ipynb", as_version=4)
    # One more cell, in this run only: which interpreter and which bayesbeam the kernel used.
    nb.cells.append(nbformat.v4.new_code_cell(
        "import sys, bayesbeam; print(sys.executable); print(bayesbeam.__file__)"))
    # The kernel's working directory is an empty folder: the example trials must come from
    # the package (find_data), not from a path relative to the repository.
    client = nbclient.NotebookClient(nb, kernel_name="python3", timeout=600,
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    # The kernel is this interpreter (jupyter_client maps the spec's "python" to
    # sys.executable), so the notebook saw this environment's bayesbeam.
    where = "".join(o.get("text", "") for o in nb.cells[-1].outputs).splitlines()
    assert where[0] == sys.executable
    assert Path(where[1]).resolve() == Path(bayesbeam.__file__).resolve()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert not errors
    last = "".join(o.get("text", "") for o in nb.cells[-2].outputs)
    assert "report.html" in last
    assert not list(tmp_path.iterdir()), "the notebook writes into its own temporary folder"
