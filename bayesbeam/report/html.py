"""One self-contained HTML page from whatever results lie in an output folder.

:func:`write_report` walks ``OUTDIR`` and renders what it finds, so every command that
writes results (``fit``, ``compare``, ``diagnose``, ``demo``) can call it at the end:

==============================  =========================================================
file in a folder                rendered as
==============================  =========================================================
``replication.json`` / ``.txt``  the study's summary table and settings (``bayesbeam demo``)
``comparison.json``             the model-comparison table (log evidence ± error, Δ,
                                probabilities, ELPD-LOO, WAIC, BIC) and the verdict
``diagnosis*.json``             named causes and per-round gains
``*.md``                        narrative (e.g. the diagnosis), a small Markdown subset
``summary.json``                one fit: posterior mean, sd and 5/50/95 % quantiles,
                                convergence diagnostics, provenance, priors
``score.json``                  one fit's evidence and criteria
``inspect.json``                what the data say before any model (``bayesbeam
                                inspect``): f1, ζ1, f2/f1 per amplitude bin, residual lines
``*.png``                       figures (data vs fits, residuals, corner plots, ...),
                                embedded as base64 ``data:`` URIs
==============================  =========================================================

The page has no external resources (no scripts, style sheets, fonts or images from
elsewhere), so it can be mailed or archived as one file; figures are embedded as
base64 PNG. Folders are shown in path order, each as a section, nested folders
(e.g. the fits of a comparison) as collapsible sub-sections.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from bayesbeam._util import interval_digits, write_text_atomic

__all__ = ["REPORT_NAME", "ReportError", "build_report", "markdown_to_html", "write_report"]

#: File name of the report inside the output folder.
REPORT_NAME = "report.html"
#: Figures in this order first (by file name), the rest alphabetically.
_FIGURE_ORDER = ("fits.png", "fit.png", "zeta_vs_f.png", "residual_spectrum.png",
                 "comparison.png", "corner.png", "trace.png")
#: Skip images larger than this (bytes); the page says so instead.
MAX_IMAGE_BYTES = 8_000_000

_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:0 auto;
max-width:1200px;padding:1em 2em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0;font-size:.88em}
th,td{border:1px solid #ccc;padding:.2em .5em;text-align:right;white-space:nowrap}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}
pre{background:#f7f7f7;padding:.6em;overflow-x:auto;font-size:.82em}
img{max-width:100%;height:auto;border:1px solid #ddd;margin:.3em 0;display:block}
details{margin:.4em 0 .4em 1em;border-left:3px solid #ddd;padding-left:.8em}
summary{cursor:pointer;font-weight:600}.muted{color:#777;font-size:.85em}
.verdict{font-weight:600}.warn{color:#a40}nav ul{columns:3;font-size:.9em}
"""


class ReportError(ValueError):
    """The output folder cannot be reported (missing, or not a folder)."""


# --------------------------------------------------------------------------- helpers


def _esc(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _fmt(x: Any, spec: str = ".4g") -> str:
    if x is None:
        return "n/a"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, float)):
        try:
            return format(x, spec)
        except (TypeError, ValueError):
            return str(x)
    return str(x)


def _pm(x: Any, e: Any, spec: str = ".2f") -> str:
    if x is None:
        return "n/a"
    return f"{_fmt(x, spec)} ± {_fmt(e, spec)}" if e is not None else _fmt(x, spec)


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as err:
        return {"_error": f"could not read {path.name}: {err}"}


def _table(head: list[str], rows: Iterable[list[str]], cls: str = "") -> str:
    out = [f'<table class="{cls}"><thead><tr>'
           + "".join(f"<th>{_esc(h)}</th>" for h in head) + "</tr></thead><tbody>"]
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{_esc(c)}</td>" for c in r) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _img(path: Path) -> str:
    data = path.read_bytes()
    if len(data) > MAX_IMAGE_BYTES:
        return f'<p class="warn">{_esc(path.name)}: {len(data)} bytes, too large to embed.</p>'
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        return f'<p class="warn">{_esc(path.name)} is not a PNG file; not embedded.</p>'
    b64 = base64.b64encode(data).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{b64}" alt="{_esc(path.name)}">'
            f'<figcaption class="muted">{_esc(path.name)}</figcaption></figure>')


def _figures(folder: Path) -> str:
    pngs = {p.name: p for p in folder.glob("*.png")  # not a write in progress (.name.tmp)
            if p.is_file() and not p.name.startswith(".")}
    names = [n for n in _FIGURE_ORDER if n in pngs] + sorted(set(pngs) - set(_FIGURE_ORDER))
    return "".join(_img(pngs[n]) for n in names)


_INLINE = [
    (re.compile(r"\*\*(.+?)\*\*"), r"<b>\1</b>"),
    (re.compile(r"`([^`]+)`"), r"<code>\1</code>"),
]


def markdown_to_html(text: str) -> str:
    """Render a small Markdown subset as HTML (escaped: no raw HTML passes through).

    Supported: ``#``–``####`` headings, ``-``/``*`` bullet lists, ``1.`` numbered
    lists (indented continuation lines join the item), fenced code blocks,
    ``**bold**``, ```code```, and paragraphs separated by blank lines.

    Parameters
    ----------
    text : str

    Returns
    -------
    str
        HTML fragment.
    """
    out: list[str] = []
    para: list[str] = []
    lst: str | None = None
    code: list[str] | None = None

    def inline(s: str) -> str:
        s = _esc(s)
        for pat, rep in _INLINE:
            s = pat.sub(rep, s)
        return s

    def flush_para() -> None:
        if para:
            out.append("<p>" + inline(" ".join(para)) + "</p>")
            para.clear()

    def close_list() -> None:
        nonlocal lst
        if lst:
            out[-1] += f"</li></{lst}>"
            lst = None

    for raw in text.splitlines():
        line = raw.rstrip()
        if code is not None:
            if line.strip().startswith("```"):
                out.append("<pre>" + _esc("\n".join(code)) + "</pre>")
                code = None
            else:
                code.append(raw)
            continue
        if line.strip().startswith("```"):
            flush_para()
            close_list()
            code = []
            continue
        m_h = re.match(r"^(#{1,4})\s+(.*)$", line)
        m_ul = re.match(r"^\s*[-*]\s+(.*)$", line)
        m_ol = re.match(r"^\s*\d+\.\s+(.*)$", line)
        if not line.strip():
            flush_para()
            close_list()
        elif m_h:
            flush_para()
            close_list()
            level = min(len(m_h.group(1)) + 2, 6)  # the page's own h1/h2 stay above
            out.append(f"<h{level}>{inline(m_h.group(2))}</h{level}>")
        elif m_ul or m_ol:
            flush_para()
            kind = "ul" if m_ul else "ol"
            item = inline((m_ul or m_ol).group(1))
            if lst != kind:
                close_list()
                out.append(f"<{kind}><li>{item}")
                lst = kind
            else:
                out[-1] += f"</li><li>{item}"
        elif lst and raw[:1].isspace():
            out[-1] += " " + inline(line.strip())
        else:
            close_list()
            para.append(line.strip())
    if code is not None:
        out.append("<pre>" + _esc("\n".join(code)) + "</pre>")
    flush_para()
    close_list()
    return "\n".join(out)


# --------------------------------------------------------------------------- sections


def _checks_html(summary: dict) -> str:
    """Mesh and adequacy lines of a fit (absent in results made before these checks)."""
    out = []
    mesh = summary.get("mesh") or {}
    if mesh.get("summary"):
        cls = "" if mesh.get("converged") else "warn"
        out.append(f'<p class="{cls}">Mesh: {_esc(mesh["summary"])}</p>')
    ad = summary.get("adequacy") or {}
    if ad.get("summary"):
        cls = "" if ad.get("ok") else "warn"
        out.append(f'<p class="{cls}">Adequacy: {_esc(ad["summary"])}</p>')
    return "".join(out)


def _posterior_cells(v: dict) -> list[str]:
    """Mean, sd, 5 %, 50 %, 95 % with enough digits that the interval shows (not 7.000e10 x3)."""
    try:
        d = interval_digits(*(float(v[k]) for k in ("q50", "q05", "q95")), minimum=4)
    except (KeyError, TypeError, ValueError):
        d = 4
    return [_fmt(v.get("mean"), f"#.{d}g"), _fmt(v.get("sd"), ".2g"),
            *(_fmt(v.get(k), f"#.{d}g") for k in ("q05", "q50", "q95"))]


def _fit_section(summary: dict, score: dict | None) -> str:
    if "_error" in summary:
        return f'<p class="warn">{_esc(summary["_error"])}</p>'
    parts = []
    post = summary.get("posterior", {})
    if post:
        rows = [[name, *_posterior_cells(v)] for name, v in post.items()]
        parts.append(_table(["parameter (SI)", "mean", "sd", "5 %", "50 %", "95 %"], rows))
    diag = summary.get("diagnostics", {})
    conv = summary.get("converged", diag.get("converged"))
    state = "converged" if conv else "NOT converged (treat with caution)"
    parts.append(
        f'<p class="{"" if conv else "warn"}">Sampler: {_esc(state)}; ESS min '
        f"{_esc(_fmt(summary.get('ess_min'), '.0f'))}, τ max "
        f"{_esc(_fmt(summary.get('tau_max'), '.1f'))} steps, R-hat max "
        f"{_esc(_fmt(summary.get('rhat_max'), '.3f'))}, "
        f"{_esc(_fmt(diag.get('n_samples'), 'd'))} samples, "
        f"{_esc(_fmt(summary.get('seconds'), '.1f'))} s.</p>"
    )
    parts.append(_checks_html(summary))
    if score and "_error" not in score:
        rows = [[
            _pm(score.get("log_evidence"), score.get("log_evidence_err")),
            _fmt(score.get("laplace_log_evidence"), ".2f"),
            _fmt(score.get("max_loglik"), ".2f"),
            _pm(score.get("elpd_loo"), score.get("elpd_loo_se"), ".1f"),
            _fmt(score.get("waic"), ".1f"), _fmt(score.get("aic"), ".1f"),
            _fmt(score.get("bic"), ".1f"), _fmt(score.get("n_bad_pareto_k"), "d"),
        ]]
        parts.append(_table(["log Z ± err", "Laplace log Z", "max log L", "ELPD-LOO ± se",
                             "WAIC", "AIC", "BIC", "Pareto k > thr."], rows))
        notes = score.get("notes") or []
        if notes:
            parts.append("<ul class=\"muted\">" + "".join(f"<li>{_esc(n)}</li>" for n in notes)
                         + "</ul>")
    prov = summary.get("provenance", {})
    settings = summary.get("settings", {})
    if prov or settings:
        keep = {k: prov.get(k) for k in ("created", "trial", "data_sha256", "model", "versions",
                                         "python", "platform") if k in prov}
        blob = json.dumps({"provenance": keep, "settings": settings,
                           "priors": summary.get("priors", {})}, indent=1, default=str)
        parts.append("<details><summary>Provenance, settings and priors</summary><pre>"
                     + _esc(blob) + "</pre></details>")
    return "".join(parts)


def _comparison_section(comp: dict) -> str:
    if "_error" in comp:
        return f'<p class="warn">{_esc(comp["_error"])}</p>'
    tied = set(comp.get("indistinguishable") or [])
    rows = []
    for m in comp.get("models", []):
        rows.append([
            m.get("name", "?") + (" *" if m.get("name") in tied else ""),
            _fmt(m.get("n_params"), "d"),
            _fmt(m.get("max_loglik"), ".1f"),
            _pm(m.get("log_evidence"), m.get("log_evidence_err")),
            _pm(m.get("delta_log_evidence"), m.get("delta_log_evidence_err")),
            _pm(m.get("probability"), m.get("probability_err"), ".3f"),
            _pm(m.get("elpd_loo"), m.get("elpd_loo_se"), ".1f"),
            _pm(m.get("delta_elpd_loo"), m.get("delta_elpd_loo_se"), ".1f"),
            _fmt(m.get("waic"), ".1f"),
            _fmt(m.get("bic"), ".1f"),
            _fmt(m.get("converged")),
            {True: "yes", False: "NO", None: "n/a"}[m.get("adequate")],
        ])
    head = ["model", "k", "max log L", "log Z ± err", "Δ log Z", "P(M|D)", "ELPD-LOO ± se",
            "Δ ELPD ± se", "WAIC", "BIC", "converged", "adequate"]
    parts = [_table(head, rows, "comparison")]
    parts.append('<p class="muted">* tied with the best: '
                 + _esc(comp.get("tie_rule", "within the evidence error")) + "</p>")
    if comp.get("verdict"):
        parts.append(f'<p class="verdict">{_esc(comp["verdict"])}</p>')
    return "".join(parts)


def _diagnosis_section(d: dict) -> str:
    if "_error" in d:
        return f'<p class="warn">{_esc(d["_error"])}</p>'
    causes = d.get("named_causes") or []
    parts = [
        f"<p>Baseline <code>{_esc(d.get('baseline', '?'))}</code> → final model "
        f"<code>{_esc(d.get('final_model', '?'))}</code>; named causes: "
        f"<b>{_esc(', '.join(causes) if causes else 'none')}</b>.</p>"
    ]
    rows = []
    for r in d.get("rounds") or []:
        rows.append([
            str(r.get("cause")), ", ".join(r.get("equivalent") or []) or "-",
            _pm(r.get("delta_log_evidence"), r.get("delta_log_evidence_err"), ".1f"),
            _pm(r.get("delta_elpd"), r.get("delta_elpd_se"), ".1f"),
            f"{_fmt(r.get('rms_before'), '.3g')} → {_fmt(r.get('rms_after'), '.3g')}",
        ])
    if rows:
        parts.append(_table(["cause", "equivalent", "Δ log Z ± err", "Δ ELPD ± se",
                             "RMS residual"], rows))
    return "".join(parts)


def _replication_section(rep: dict) -> str:
    if "_error" in rep:
        return f'<p class="warn">{_esc(rep["_error"])}</p>'
    parts = []
    table = rep.get("table_text")
    if table:
        parts.append("<pre>" + _esc(table) + "</pre>")
    for key in ("conclusions", "settings_text"):
        if rep.get(key):
            parts.append("<p>" + _esc(rep[key]) + "</p>")
    if rep.get("joint_table_text"):
        parts.append("<h3>Each beam's trials fitted jointly</h3><pre>"
                     + _esc(rep["joint_table_text"]) + "</pre>")
    timing = rep.get("timing")
    if timing:
        parts.append("<p class=\"muted\">Timing: " + _esc(json.dumps(timing, default=str))
                     + "</p>")
    prov = {k: rep.get(k) for k in ("provenance", "settings", "data") if k in rep}
    if prov:
        parts.append("<details><summary>Provenance and settings</summary><pre>"
                     + _esc(json.dumps(prov, indent=1, default=str)) + "</pre></details>")
    return "".join(parts)


def _inspect_section(rec: dict) -> str:
    """Amplitude bins and residual lines of an ``inspect.json`` record."""
    head = ["tip amplitude [mm]", "windows", "f1 [Hz]", "ζ1", "f2/f1", "ζ2"]
    rows = [[_fmt(None if b.get("amplitude_m") is None else 1e3 * b["amplitude_m"], ".3g"),
             str(b.get("n", "")), _pm(b.get("f1"), b.get("f1_se"), ".5f"),
             _pm(b.get("zeta1"), b.get("zeta1_se"), ".5f"),
             _pm(b.get("ratio"), b.get("ratio_se"), ".4f"),
             _pm(b.get("zeta2"), b.get("zeta2_se"), ".5f")]
            for b in rec.get("bins", [])]
    lines = rec.get("residual_lines", [])
    txt = ("; ".join(f"{_fmt(x.get('frequency_hz'), '.2f')} Hz ({_esc(x.get('label'))})"
                     for x in lines) if lines else "none above the threshold")
    return (f"<p>{_esc(rec.get('trial', ''))}: {len(rec.get('windows', {}).get('centre_s', []))}"
            f" windows of {_fmt(rec.get('window_s'), '.3g')} s on the raw stamps, no model. "
            f"Residual lines: {txt}.</p>" + _table(head, rows))


def _sections(folder: Path) -> list[tuple[str | None, str, str]]:
    """Return the folder's result sections as ``(run id or None, file name, HTML)``."""
    parts: list[tuple[str | None, str, str]] = []

    def add(name: str, record: Any, html_text: str) -> None:
        run = record.get("run_id") if isinstance(record, dict) else None
        parts.append((run if isinstance(run, str) else None, name, html_text))

    if (folder / "inspect.json").is_file():
        rec = _read_json(folder / "inspect.json")
        add("inspect.json", rec, "<h3>What the data say before any model</h3>"
            + _inspect_section(rec))
    rep = folder / "replication.json"
    if rep.is_file():
        rec = _read_json(rep)
        add(rep.name, rec, _replication_section(rec))
    elif (folder / "replication.txt").is_file():
        add("replication.txt", None,
            "<pre>" + _esc((folder / "replication.txt").read_text("utf-8")) + "</pre>")
    if (folder / "comparison.json").is_file():
        rec = _read_json(folder / "comparison.json")
        add("comparison.json", rec, "<h3>Model comparison</h3>" + _comparison_section(rec))
    for dj in sorted(folder.glob("diagnosis*.json")):
        rec = _read_json(dj)
        add(dj.name, rec, "<h3>Diagnosis</h3>" + _diagnosis_section(rec))
    for md in sorted(folder.glob("*.md")):
        try:
            add(md.name, None, markdown_to_html(md.read_text(encoding="utf-8")))
        except (OSError, UnicodeDecodeError) as err:
            add(md.name, None,
                f'<p class="warn">could not read {_esc(md.name)}: {_esc(err)}</p>')
    if (folder / "summary.json").is_file():
        score = _read_json(folder / "score.json") if (folder / "score.json").is_file() else None
        rec = _read_json(folder / "summary.json")
        add("summary.json", rec, _fit_section(rec, score))
    return parts


def _folder_body(folder: Path) -> str:
    """Return the folder's sections, keeping the outputs of different runs apart.

    Each command writes its run id (:mod:`bayesbeam.cli.outdir`) into its JSON outputs;
    a folder that two runs wrote into (a compare, then a fit of another model) would
    otherwise show their tables as if they were one result.
    """
    parts = _sections(folder)
    runs = sorted({r for r, _, _ in parts if r is not None})
    if len(runs) <= 1:
        return "".join(h for _, _, h in parts) + _figures(folder)
    listing = "; ".join(
        f"{r}: " + ", ".join(n for q, n, _ in parts if q == r) for r in runs)
    out = [f'<p class="warn">This folder holds the outputs of {len(runs)} different runs '
           f"({_esc(listing)}). Each run's results are shown under its own heading; the "
           "figures below cannot be told apart by run and may belong to any of them. "
           "Write each run into its own -o folder.</p>"]
    for r in runs:
        out.append(f"<h3>Run {_esc(r)}</h3>" + "".join(h for q, _, h in parts if q == r))
    rest = [h for q, _, h in parts if q is None]
    if rest:
        out.append("<h3>Files without a run id</h3>" + "".join(rest))
    out.append(_figures(folder))
    return "".join(out)


_MARKERS = ("summary.json", "comparison.json", "replication.json", "replication.txt",
            "inspect.json")


def _interesting(folder: Path) -> bool:
    return (any((folder / m).is_file() for m in _MARKERS) or any(folder.glob("*.png"))
            or any(folder.glob("diagnosis*.json")) or any(folder.glob("*.md")))


def _title_of(folder: Path, root: Path) -> str:
    rel = folder.relative_to(root).as_posix()
    return "results" if rel == "." else rel


def _render(folder: Path, root: Path, depth: int, toc: list[tuple[str, str]]) -> str:
    subs = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    inner = "".join(_render(s, root, depth + 1, toc) for s in subs)
    if not _interesting(folder) and not inner:
        return ""
    title = _title_of(folder, root)
    anchor = "s-" + re.sub(r"[^A-Za-z0-9_-]+", "-", title)
    body = _folder_body(folder) if _interesting(folder) else ""
    if depth <= 1:
        toc.append((anchor, title))
        return f'<section id="{anchor}"><h2>{_esc(title)}</h2>{body}{inner}</section>'
    return (f'<details id="{anchor}"><summary>{_esc(folder.name)}</summary>{body}{inner}'
            "</details>")


def build_report(outdir: str | Path, *, title: str | None = None) -> str:
    """Return the HTML text of the report of ``outdir`` (see the module docstring).

    Parameters
    ----------
    outdir : str or Path
        Output folder of a fit, comparison, diagnosis or study.
    title : str, optional
        Page title (default: "bayesbeam report: <folder name>").

    Returns
    -------
    str
        A complete HTML document with every figure embedded.

    Raises
    ------
    ReportError
        If ``outdir`` is not an existing folder.
    """
    root = Path(outdir)
    if not root.is_dir():
        raise ReportError(f"{root} is not a folder; give the output folder of a bayesbeam run")
    from bayesbeam._util import distribution_version

    title = title or f"bayesbeam report: {root.resolve().name}"
    toc: list[tuple[str, str]] = []
    top = _folder_body(root) if _interesting(root) else ""
    subs = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    body = "".join(_render(s, root, 1, toc) for s in subs)
    if not top and not body:
        top = ('<p class="warn">No results found in this folder (no summary.json, '
               "comparison.json, diagnosis*.json, *.md or *.png).</p>")
    nav = ""
    if len(toc) > 1:
        nav = ("<nav><ul>" + "".join(f'<li><a href="#{a}">{_esc(t)}</a></li>' for a, t in toc)
               + "</ul></nav>")
    when = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{_esc(title)}</title><style>{_CSS}</style></head><body>\n"
        f"<h1>{_esc(title)}</h1>\n"
        f'<p class="muted">bayesbeam {_esc(distribution_version("bayesbeam"))}; '
        f'generated {_esc(when)} from '
        f"<code>{_esc(root.resolve())}</code>. Self-contained: every figure is embedded.</p>\n"
        f"{nav}\n{top}\n{body}\n</body></html>\n"
    )


def write_report(outdir: str | Path, *, path: str | Path | None = None,
                 title: str | None = None) -> Path:
    """Write ``report.html`` (one self-contained page) for the results in ``outdir``.

    Parameters
    ----------
    outdir : str or Path
        Output folder to report on.
    path : str or Path, optional
        Where to write (default ``outdir/report.html``).
    title : str, optional
        Page title.

    Returns
    -------
    Path
        The HTML file written.
    """
    text = build_report(outdir, title=title)
    out = Path(outdir) / REPORT_NAME if path is None else Path(path)
    write_text_atomic(out, text)
    return out
