"""`rbstudy report`: one self-contained HTML page per study, from its dataset only.

``<out>/index.html`` holds the study's config, the per-scheme table (observed order with the
dt range it was fitted on, errors at the largest and smallest dt, kernel time per body-step,
stable range, invariants kept), every figure of `rbstudy.plots` (PNG files beside it in
``<out>/figures/``, SVG too) and the provenance recorded in the dataset.
"""

import html
import pathlib

import numpy as np

from rbstudy.plots import CAPTIONS, all_figures
from rbstudy.schemes import SCHEMES
from rbstudy.store import write_text_atomic
from rbstudy.summary import KEPT_TOLERANCE, order_text, scheme_rows

__all__ = ["write_report"]

_STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
pre { background: #f5f5f5; padding: 1em; overflow-x: auto; font-size: 0.85em; }
figure { margin: 2em 0; } img { max-width: 100%; }
figcaption { font-size: 0.9em; color: #444; }
"""


def _number(value, spec=".3e", unit=""):
    if value is None or not np.isfinite(value):
        return "-"
    return f"{value:{spec}}{unit}"


def _scheme_table(rows):
    head = ("scheme", "nominal order", "observed order", "fitted over dt (s)",
            "error at largest dt", "error at smallest dt", "ns per body-step",
            "largest stable dt|w0|", "smallest unstable dt|w0|", "unstable cases",
            "invariants kept")
    lines = ["<table>", "<tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"]
    for row in rows:
        scheme = SCHEMES.get(row["scheme"])
        order = order_text(row)
        fit = "-" if not row["fit_dt"] else f"{row['fit_dt'][0]:.4g} to {row['fit_dt'][1]:.4g}"
        large = _number(row["error"], unit=" rad")
        if "error_dt" in row:
            large += f" (dt {row['error_dt']:g})"
        small = _number(row.get("error_small"), unit=" rad")
        if "error_small_dt" in row:
            small += f" (dt {row['error_small_dt']:g})"
        cells = (row["scheme"], scheme.order if scheme else "-", order, fit, large, small,
                 _number(row["ns_per_step"], ".0f"), _number(row["stable_hw"], ".3g"),
                 _number(row["unstable_hw"], ".3g"), f"{row['unstable']} of {row['cases']}",
                 ", ".join(row["kept"]) or "-")
        lines.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
    lines.append("</table>")
    return "\n".join(lines)


def _caption(name):
    key = next((k for k in CAPTIONS if name.startswith(k)), None)
    return CAPTIONS.get(key, "")


def write_report(ds, out):
    """Write ``out/index.html`` and ``out/figures/`` for dataset ``ds``; returns the index path."""
    out = pathlib.Path(out)
    figures = all_figures(ds, out / "figures")
    rows = scheme_rows(ds)
    title = html.escape(ds.attrs.get("title", ds.attrs.get("study", "rbstudy results")))
    dims = ", ".join(f"{d} ({ds.sizes[d]})" for d in ds["status"].dims) or "one case"
    parts = [
        "<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
        f"<title>{title}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{title}</h1>",
        f"<p>Study <code>{html.escape(str(ds.attrs.get('study', '')))}</code>: "
        f"{int(ds['status'].size)} cases over {html.escape(dims)}.</p>",
        "<h2>Schemes</h2>",
        "<p>Observed order: least-squares slope of the final orientation error against dt, "
        "fitted for each value of the other swept axes over the points neither at round-off "
        "(1e-11 rad) nor above 0.1 rad; a range gives the smallest and largest fit. Errors "
        "are the worst over the other axes. ns per body-step: median kernel CPU time per "
        "case divided by its steps. Invariants kept: largest relative drift of every stable "
        f"case below {KEPT_TOLERANCE:g}.</p>",
        _scheme_table(rows),
        "<h2>Figures</h2>",
    ]
    for png in figures:
        relative = png.relative_to(out).as_posix()
        parts.append(f"<figure><img src='{relative}' alt='{png.stem}'>"
                     f"<figcaption><b>{png.stem}</b>: {html.escape(_caption(png.stem))} "
                     f"(<a href='{relative[:-4]}.svg'>SVG</a>)</figcaption></figure>")
    parts += ["<h2>Configuration</h2>", f"<pre>{html.escape(ds.attrs.get('config', ''))}</pre>",
              "<h2>Provenance</h2>", "<table>"]
    for key in ("source", "history", "versions", "platform", "python", "config_path"):
        value = html.escape(str(ds.attrs.get(key, "-"))).replace("\n", "<br>")
        parts.append(f"<tr><td>{key}</td><td style='text-align:left'>{value}</td></tr>")
    parts += ["</table>", "</body></html>"]
    index = out / "index.html"
    write_text_atomic("\n".join(parts), index)
    return index
