"""`rbstudy report`: one self-contained HTML page per study, from its dataset only.

``<out>/index.html`` holds the study's config, the per-scheme table (observed order with the
dt range it was fitted on and the slope of its finest pair, errors at the largest and smallest
dt, kernel time per body-step, accurate range, invariants kept), every figure of
`rbstudy.analysis.plots` (PNG files beside it in ``<out>/figures/``, SVG too), the figures
the study could not show and why, and the provenance recorded in the dataset. A report folder
belongs to one study (``.rbstudy-report`` names it): writing another study's report there is
refused.
"""

import html
import pathlib

from rbstudy.analysis.plots import ALL_FORMATS, CAPTIONS, all_figures
from rbstudy.analysis.summary import (
    ERROR_MEASURES,
    UNCERTAINTY_FACTOR,
    format_table,
    scheme_rows,
)
from rbstudy.errors import InputError
from rbstudy.physics.metrics import (
    MAX_SLOPE_DRIFT,
    MIN_ASYMPTOTIC_POINTS,
    MIN_CONVERGENCE_ORDER,
    ORDER_SPREAD,
)
from rbstudy.pipeline.store import write_text_atomic
from rbstudy.reader import Reader

__all__ = ["write_report", "MARKER"]

# The file that names the study a report folder belongs to.
MARKER = ".rbstudy-report"

_STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
pre { background: #f5f5f5; padding: 1em; overflow-x: auto; font-size: 0.85em; }
figure { margin: 2em 0; } img { max-width: 100%; }
figcaption { font-size: 0.9em; color: #444; }
"""


def _caption(name):
    key = next((k for k in CAPTIONS if name.startswith(k)), None)
    return CAPTIONS.get(key, "")


def _claim(out, study):
    """Make ``out`` this study's report folder, or refuse one that belongs to another."""
    marker = out / MARKER
    owner = marker.read_text().strip() if marker.is_file() else None
    if owner is not None and owner != study:
        raise InputError(f"holds the report of study {owner!r}, not {study!r}",
                         "give --out another folder", str(out))
    if owner is None and out.is_dir() and any(out.iterdir()):
        raise InputError("is not empty and holds no rbstudy report",
                         "give --out a new or empty folder", str(out))
    write_text_atomic(study + "\n", marker)


def write_report(ds, out, processes=1):
    """Write ``out/index.html`` and ``out/figures/`` for dataset ``ds``, the figures drawn in
    ``processes`` processes (`rbstudy.analysis.plots.all_figures`); returns the index path."""
    out = pathlib.Path(out)
    # before the folder is claimed: the study names the figure files
    study = Reader(str(out)).folder_name(str(ds.attrs.get("study", "results")), "study")
    _claim(out, study)
    figures = all_figures(ds, out / "figures", ALL_FORMATS, processes)  # PNG shown, SVG linked
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
        "<p>The table <code>rbstudy sweep --wide</code> prints, its footnotes under it. "
        "No order is fitted through an error below "
        f"{UNCERTAINTY_FACTOR:g}x its integrated reference's uncertainty "
        "(reference_uncertainty). The asymptotic range: the longest run of at least "
        f"{MIN_ASYMPTOTIC_POINTS} neighbouring steps with errors between {floor:g} and "
        f"{ceiling:g} rad whose local slopes agree within {ORDER_SPREAD:g} of the fitted "
        f"order (itself at least {MIN_CONVERGENCE_ORDER:g}) and do not drift by more "
        f"than {MAX_SLOPE_DRIFT:g} in their trend; among equally long runs, the finest. "
        f"Accuracy bound of this study: {ds.attrs.get('accuracy_bound', '-')} (rad for the "
        "orientation error at any sample, relative for energy and |L|). ns per step: "
        "the scheme's kernel CPU time over all its steps. dt|w0| is the step parameter of a physical body (a "
        "stress body beyond the triangle inequality precesses faster than |w0|).</p>",
        format_table(rows, wide=True, fmt="html"),
        "<h2>Figures</h2>",
    ]
    for png in figures.written:
        relative = png.relative_to(out).as_posix()
        name = png.stem.removeprefix(f"{study}_")
        parts.append(f"<figure><img src='{relative}' alt='{png.stem}'>"
                     f"<figcaption><b>{name}</b>: {html.escape(_caption(name))} "
                     f"(<a href='{relative[:-4]}.svg'>SVG</a>)</figcaption></figure>")
    if figures.absent:
        parts += ["<h3>Figures not drawn</h3>", "<ul>"]
        parts += [f"<li><b>{html.escape(name)}</b>: {html.escape(reason)}</li>"
                  for name, reason in figures.absent.items()]
        parts.append("</ul>")
    parts += ["<h2>Configuration</h2>", f"<pre>{html.escape(ds.attrs.get('config', ''))}</pre>",
              "<h2>Provenance</h2>", "<table>"]
    for key in ("source", "history", "versions", "platform", "python", "config_path"):
        value = html.escape(str(ds.attrs.get(key, "-"))).replace("\n", "<br>")
        parts.append(f"<tr><td>{key}</td><td style='text-align:left'>{value}</td></tr>")
    parts += ["</table>", "</body></html>"]
    index = out / "index.html"
    write_text_atomic("\n".join(parts), index)
    return index
