"""HTML report: content, self-containment, and a real headless browser (Debian's chromium)."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from bayesbeam.report.html import ReportError, build_report, markdown_to_html, write_report

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None,
    reason="chromium not installed (Debian: apt-get install -y chromium); browser tests skipped",
)


def _png(path, seed: int) -> None:
    from matplotlib.figure import Figure

    rng = np.random.default_rng(seed)
    fig = Figure(figsize=(4, 3))
    ax = fig.subplots()
    ax.plot(np.cumsum(rng.standard_normal(200)))
    ax.set_title(path.stem)
    fig.savefig(path, dpi=60)


@pytest.fixture
def outdir(tmp_path):
    """A folder shaped like the output of fit, compare, diagnose and demo runs."""
    root = tmp_path / "out"
    fit = root / "beam1-trial1" / "viscous"
    fit.mkdir(parents=True)
    summary = {
        "model": "viscous", "converged": False, "ess_min": 85.0, "tau_max": 12.5,
        "rhat_max": 1.01, "seconds": 3.2,
        "posterior": {"E": {"mean": 5.2e10, "sd": 1e8, "q05": 5.18e10, "q50": 5.2e10,
                            "q95": 5.22e10},
                      "gamma": {"mean": 0.09, "sd": 1e-4, "q05": 0.0898, "q50": 0.09,
                                "q95": 0.0902}},
        "diagnostics": {"n_samples": 4800, "converged": False},
        "settings": {"n_elements": 8, "seed": 0},
        "priors": {"E": {"kind": "LogUniform"}},
        "provenance": {"data_sha256": "ab" * 32, "model": "viscous",
                       "versions": {"bayesbeam": "0.1.0"}},
    }
    (fit / "summary.json").write_text(json.dumps(summary))
    (fit / "score.json").write_text(json.dumps({
        "log_evidence": 11068.7, "log_evidence_err": 0.01, "elpd_loo": 11099.1,
        "elpd_loo_se": 40.3, "waic": -22198.3, "aic": -22201.0, "bic": -22181.2,
        "max_loglik": 11104.9, "laplace_log_evidence": 11069.0, "n_bad_pareto_k": 0,
        "notes": ["sampler did not meet its convergence criteria <b>"]}))
    for name in ("fit.png", "corner.png", "residual_spectrum.png"):
        _png(fit / name, len(name))
    comp = root / "beam1-trial1"
    (comp / "comparison.json").write_text(json.dumps({
        "models": [{"name": "viscous", "n_params": 4, "log_evidence": 11068.7,
                    "log_evidence_err": 0.01, "delta_log_evidence": -93.2,
                    "delta_log_evidence_err": 0.3, "probability": 0.0, "probability_err": 0.0,
                    "elpd_loo": 11099.1, "elpd_loo_se": 40.3, "waic": -22198.3,
                    "bic": -22181.2, "converged": True},
                   {"name": "viscous+kv", "n_params": 5, "log_evidence": 11161.9,
                    "log_evidence_err": 0.3, "delta_log_evidence": 0.0,
                    "delta_log_evidence_err": 0.0, "probability": 1.0,
                    "probability_err": 0.0, "elpd_loo": 11190.0, "elpd_loo_se": 30.0,
                    "waic": -22380.0, "bic": -22300.0, "converged": True}],
        "best": "viscous+kv", "indistinguishable": ["viscous+kv"],
        "verdict": "Verdict: viscous+kv is favoured over viscous by 93.2 nats."}))
    _png(comp / "comparison.png", 7)
    diag = root / "diagnosis-beam1-trial1"
    diag.mkdir()
    (diag / "diagnosis.json").write_text(json.dumps({
        "baseline": "viscous", "final_model": "viscous+kv", "named_causes": ["kv"],
        "rounds": [{"cause": "kv", "equivalent": ["sh"], "delta_log_evidence": 93.2,
                    "delta_log_evidence_err": 0.3, "delta_elpd": 90.9, "delta_elpd_se": 15.0,
                    "rms_before": 4.1e-5, "rms_after": 1.3e-5}]}))
    (diag / "diagnosis.md").write_text(
        "# Diagnosis of trial `beam1-trial1`\n\n## Named causes\n\n"
        "1. **kv**: Δ log Z = 93.2 ± 0.3\n   continued line\n- a <script>alert(1)</script>\n")
    _png(diag / "signatures_before.png", 11)
    (root / "replication.json").write_text(json.dumps({
        "table_text": "beam  model  ...", "conclusions": "beam1: favoured viscous+kv.",
        "timing": {"total_s": 12.0}}))
    (root / "empty-folder").mkdir()
    return root


def test_markdown_subset_is_escaped_and_structured():
    h = markdown_to_html("# T\n\nSome **bold** and `code`.\n\n- a <b>\n- b\n\n1. one\n"
                         "   more\n2. two\n\n```\nx < 1\n```\n")
    assert "<h3>T</h3>" in h
    assert "<b>bold</b>" in h and "<code>code</code>" in h
    assert "&lt;b&gt;" in h and "<b>\n" not in h  # raw HTML is escaped
    assert h.count("<li>") == 4 and "<ol>" in h and "<ul>" in h
    assert "one more" in h  # continuation line joins its item
    assert "<pre>x &lt; 1</pre>" in h


def test_report_has_every_section_and_is_self_contained(outdir):
    path = write_report(outdir)
    assert path == outdir / "report.html"
    text = path.read_text(encoding="utf-8")
    # Figures: 3 fit figures + comparison + signature figure, all embedded.
    srcs = re.findall(r'<img src="([^"]+)"', text)
    assert len(srcs) == 5
    assert all(s.startswith("data:image/png;base64,") for s in srcs)
    for s in srcs:  # each decodes to a PNG
        assert base64.b64decode(s.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    # No external resources of any kind.
    assert not re.search(r'(src|href)="(https?:|//)', text)
    assert "<script" not in text  # the markdown's <script> arrived escaped
    assert "&lt;script&gt;" in text
    for needle in ("Model comparison", "viscous+kv *", "Verdict: viscous+kv",
                   "Named causes", "11068.70 ± 0.01", "NOT converged",
                   "sampler did not meet its convergence criteria &lt;b&gt;", "beam1: favoured",
                   "Diagnosis", "93.2 ± 0.3", "5.200e+10", "5.180e+10"):
        assert needle in text, needle
    assert "empty-folder" not in text  # folders without results are left out


def test_report_of_missing_or_empty_folder(tmp_path):
    with pytest.raises(ReportError, match="not a folder"):
        build_report(tmp_path / "nope")
    assert "No results found" in build_report(tmp_path)


def _chromium(args, tmp_path, timeout=120):
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp_path / 'chromium-profile'}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)


# Injected into a copy of the report: records errors and console.error calls from the
# first moment, then after the load event writes the image check into the DOM.
_PROBE_HEAD = """<script>window.__errs=[];
window.addEventListener('error',function(e){__errs.push('error: '+(e.message||e.type));},true);
(function(){var ce=console.error;console.error=function(){__errs.push('console.error: '+
Array.prototype.join.call(arguments,' '));ce.apply(console,arguments);};})();</script>"""
_PROBE_TAIL = """<script>window.addEventListener('load',function(){
var imgs=Array.prototype.slice.call(document.images);
var r={n:imgs.length,bad:imgs.filter(function(i){return !(i.complete&&i.naturalWidth>0);})
.map(function(i){return i.alt;}),errors:__errs};
var p=document.createElement('pre');p.id='probe';p.textContent=JSON.stringify(r);
document.body.appendChild(p);});</script>"""


@needs_chromium
def test_report_loads_in_headless_chromium_and_every_image_renders(outdir, tmp_path):
    text = write_report(outdir).read_text(encoding="utf-8")
    probe = tmp_path / "probe.html"
    probe.write_text(text.replace("<head>", "<head>" + _PROBE_HEAD, 1)
                     .replace("</body>", _PROBE_TAIL + "</body>", 1), encoding="utf-8")
    res = _chromium(["--virtual-time-budget=10000", "--dump-dom", probe.as_uri()], tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    m = re.search(r'<pre id="probe">(.*?)</pre>', res.stdout, re.S)
    assert m, "the load-event probe did not run: " + res.stdout[-500:]
    result = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert result["n"] == 5
    assert result["bad"] == []
    assert result["errors"] == []
    # The page's own console: chromium logs page console messages as "CONSOLE(...)".
    assert "CONSOLE" not in res.stderr or ":ERROR:CONSOLE" not in res.stderr


@needs_chromium
def test_report_screenshot_is_written_and_not_blank(outdir, tmp_path):
    from matplotlib.image import imread

    report = write_report(outdir)
    shot = tmp_path / "report.png"
    res = _chromium([f"--screenshot={shot}", "--window-size=1200,1600", "--hide-scrollbars",
                     report.as_uri()], tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    assert shot.is_file() and shot.stat().st_size > 10_000
    img = imread(shot)
    assert img.shape[:2] == (1600, 1200)
    gray = img[..., :3].mean(axis=2)
    # Not blank: a rendered page of text, tables and plots has many non-white pixels
    # (a blank page has none; 2 % is far below what the fixture's page shows).
    assert np.mean(gray < 0.9) > 0.02
    assert gray.std() > 0.05


def test_outputs_of_two_runs_in_one_folder_are_kept_apart(outdir):
    """A compare and then a fit of another model into one folder: the page says so and
    shows each run's tables under its own run id instead of one mixed result."""
    folder = outdir / "beam1-trial1"
    comp = json.loads((folder / "comparison.json").read_text())
    (folder / "comparison.json").write_text(json.dumps({**comp, "run_id": "compare-A"}))
    summary = json.loads((folder / "viscous" / "summary.json").read_text())
    (folder / "summary.json").write_text(json.dumps({**summary, "run_id": "fit-B"}))
    text = build_report(outdir)
    assert "holds the outputs of 2 different runs" in text
    assert "compare-A: comparison.json; fit-B: summary.json" in text
    a, b = text.index("<h3>Run compare-A</h3>"), text.index("<h3>Run fit-B</h3>")
    assert a < text.index("Model comparison") < b  # the comparison table under its run
    # one run per folder: no warning
    (folder / "summary.json").write_text(json.dumps({**summary, "run_id": "compare-A"}))
    assert "different runs" not in build_report(outdir)
