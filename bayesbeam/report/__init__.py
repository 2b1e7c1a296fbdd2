"""Pictures and pages: fit and residual plots, the self-contained HTML report.

Layer: above :mod:`bayesbeam.diagnosis`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "build_report": ".html",
    "markdown_to_html": ".html",
    "plot_fit": ".plots",
    "plot_residual_spectrum": ".plots",
    "PlotError": ".plots",
    "REPORT_NAME": ".html",
    "ReportError": ".html",
    "residual_summary": ".plots",
    "UNIT_LABELS": ".plots",
    "write_report": ".html",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
