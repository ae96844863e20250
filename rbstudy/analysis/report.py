"""`rbstudy report`: one self-contained HTML page per study, from its dataset only.

``<out>/index.html`` holds the study's config, the per-scheme table (observed order with the
dt range it was fitted on, errors at the largest and smallest dt, kernel time per body-step,
stable range, invariants kept), every figure of `rbstudy.analysis.plots` (PNG files beside it in
``<out>/figures/``, SVG too) and the provenance recorded in the dataset.
"""

import html
import pathlib

from rbstudy.analysis.plots import CAPTIONS, all_figures
from rbstudy.analysis.summary import ERROR_MEASURES, TABLE_NOTE, scheme_rows, table_columns
from rbstudy.physics.metrics import MIN_ASYMPTOTIC_POINTS, MIN_CONVERGENCE_ORDER, ORDER_SPREAD
from rbstudy.pipeline.store import write_text_atomic

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


def _scheme_table(rows):
    columns = table_columns(rows)
    lines = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h, _ in columns)
             + "</tr>"]
    for row in rows:
        lines.append("<tr>" + "".join(f"<td>{html.escape(cell(row))}</td>" for _, cell in columns)
                     + "</tr>")
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
    floor, ceiling = ERROR_MEASURES["orientation"][2:4]
    title = html.escape(ds.attrs.get("title", ds.attrs.get("study", "rbstudy results")))
    dims = ", ".join(f"{d} ({ds.sizes[d]})" for d in ds["status"].dims) or "one case"
    parts = [
        "<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
        f"<title>{title}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{title}</h1>",
        f"<p>Study <code>{html.escape(str(ds.attrs.get('study', '')))}</code>: "
        f"{int(ds['status'].size)} cases over {html.escape(dims)}.</p>",
        "<h2>Schemes</h2>",
        f"<p>{html.escape(TABLE_NOTE)}. The asymptotic range: the longest run of at least "
        f"{MIN_ASYMPTOTIC_POINTS} neighbouring steps with errors between {floor:g} and "
        f"{ceiling:g} rad whose local slopes agree within {ORDER_SPREAD:g} of the fitted "
        f"order, itself at least {MIN_CONVERGENCE_ORDER:g}. ns/step: the scheme's kernel CPU "
        "time over all its steps. dt|w0| is the step parameter of a physical body (a stress body "
        "beyond the triangle inequality precesses faster than |w0|).</p>",
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
