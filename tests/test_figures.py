"""Figures and report from archives only: every shipped study gives its figures (run here
shrunk: two schemes, at most three values per axis, a short run), the report parses and
every image it shows exists, and the shipped convergence study shows the nominal orders."""

import html.parser
import pathlib

import pytest
import yaml
from conftest import CONFIGS

from rbstudy.analysis.plots import all_figures
from rbstudy.analysis.summary import ERROR_MEASURES, scheme_rows
from rbstudy.cli import main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.pipeline.store import open_results
from rbstudy.schemes import SCHEMES

SHIPPED = sorted(path.name for path in CONFIGS.glob("*.yaml"))
SHRUNK_SCHEMES = ["hht", "leapfrog"]  # hht takes the option some configs set
# Samples kept per shrunk run: enough for a drift curve and a precession fit.
SHRUNK_SAMPLES = 40


def _shrink(values):
    if isinstance(values, dict) and "halving" in values:
        return {**values, "count": min(values["count"], 3)}
    if isinstance(values, dict):
        form, (start, stop, count) = next(iter(values.items()))
        return {form: [start, stop, min(count, 3)]}
    return values[-3:]  # the last values: the Abaqus flat disk (I3/I1 = 2) stays in


def shrunk_config(name, folder):
    """The shipped study ``name``, smaller but with the same dimensions and variables."""
    study = yaml.safe_load((CONFIGS / name).read_text())
    sweep = study.get("sweep", {})
    for axis, values in list(sweep.items()):
        if axis == "scheme":
            sweep[axis] = SHRUNK_SCHEMES
        elif axis == "zip":
            sweep[axis] = {dim: {a: _shrink(v) for a, v in group.items()}
                           for dim, group in values.items()}
        else:
            sweep[axis] = _shrink(values)
    interval = study["output"]["interval"]
    study["scene"]["duration"] = min(study["scene"]["duration"], SHRUNK_SAMPLES * interval)
    path = pathlib.Path(folder) / name
    path.write_text(yaml.safe_dump(study))
    return path


def expected_figures(ds):
    """A convergence figure per error measure stored and not zero everywhere, when dt is
    swept; the others by what the dataset holds."""
    names = {"stability_map"}
    if "dt" in ds.dims:
        names.add("work_precision")
        for key, (*_, variable) in ERROR_MEASURES.items():
            if variable in ds and (abs(ds[variable]) > 0).any():
                names.add(f"convergence_{key}")
    if "energy_error" in ds:
        names.add("invariant_drift")
    if "precession_frequency" in ds and "node_offset" in ds:
        names |= {"benchmark_omega_time", "benchmark_omega_xy", "benchmark_node_path"}
    return names


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_study_gives_its_figures(name, tmp_path):
    done = run_study(load_study(shrunk_config(name, tmp_path)), tmp_path / "out", quiet=True)
    ds = open_results(done.path)
    written = all_figures(ds, tmp_path / "figures")
    assert {png.stem for png in written} == expected_figures(ds)
    for png in written:
        assert png.stat().st_size > 10_000 and png.with_suffix(".svg").stat().st_size > 10_000


class _Page(html.parser.HTMLParser):
    """The images, links and table rows (as cell counts) of a page."""

    def __init__(self):
        super().__init__()
        self.images, self.links, self.rows = [], [], []

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        elif tag == "a":
            self.links.append(dict(attrs)["href"])
        elif tag == "tr":
            self.rows.append(0)
        elif tag in ("td", "th") and self.rows:
            self.rows[-1] += 1


def test_report_parses_and_every_image_exists(tmp_path, capsys):
    done = run_study(load_study(shrunk_config("abaqus_top.yaml", tmp_path)), tmp_path / "out",
                     quiet=True)
    assert main(["report", str(done.path), "--out", str(tmp_path / "report")]) == 0
    index = tmp_path / "report" / "index.html"
    parser = _Page()
    parser.feed(index.read_text())
    parser.close()
    assert len(parser.images) == len(expected_figures(open_results(done.path)))
    for source in parser.images + parser.links:
        assert (index.parent / source).is_file(), source
    text = index.read_text()
    for row in scheme_rows(open_results(done.path)):  # the table shows the summary's numbers
        assert f"<td>{row['unstable']}/{row['cases']}</td>" in text
        assert f"<td>{row['order'][0]:.2f}</td>" in text or row["order"][0] != row["order"][1]
    for scheme in SHRUNK_SCHEMES:
        assert f"<td>{scheme}</td>" in text
    assert "Provenance" in text and "history" in text


def test_the_shipped_convergence_study_shows_every_nominal_order(tmp_path):
    done = run_study(load_study(CONFIGS / "convergence_asymmetric.yaml"), tmp_path, quiet=True)
    rows = scheme_rows(open_results(done.path))
    assert {row["scheme"] for row in rows} == {n for n, s in SCHEMES.items() if not s.adaptive}
    for row in rows:
        low, high = row["order"]
        nominal = SCHEMES[row["scheme"]].order
        assert abs(low - nominal) < 0.25 and abs(high - nominal) < 0.25, row


def test_plot_refuses_a_file_that_is_not_results(tmp_path, capsys):
    bogus = tmp_path / "x.nc"
    bogus.write_text("not netCDF")
    assert main(["plot", str(bogus)]) == 2
    error = capsys.readouterr().err.strip()
    assert "cannot read it as an rbstudy results file" in error and "\n" not in error


def test_plot_select_narrows_the_cases(tmp_path, capsys):
    done = run_study(load_study(shrunk_config("abaqus_top.yaml", tmp_path)), tmp_path / "out",
                     quiet=True)
    from rbstudy.cli import _select
    narrowed = _select(open_results(done.path), ["scheme=hht", "inertia_ratio=2"], "x")
    assert (narrowed.sizes["scheme"], narrowed.sizes["inertia_ratio"]) == (1, 1)
    assert str(narrowed.scheme.values[0]) == "hht" and float(narrowed.inertia_ratio[0]) == 2.0
    assert main(["plot", str(done.path), "--out", str(tmp_path / "one"),
                 "--select", "scheme=hht", "--select", "inertia_ratio=2"]) == 0
    assert len(list((tmp_path / "one").glob("*.png"))) == len(expected_figures(narrowed))
    for bad, message in ((["--select", "dt=fast"], "--select dt=fast: dt takes a number"),
                         (["--select", "time=1"], "'time' is not a swept dimension")):
        assert main(["plot", str(done.path), "--out", str(tmp_path / "x"), *bad]) == 2
        assert message in capsys.readouterr().err
    assert main(["plot", str(done.path), "--select", "dt=0.01"]) == 2
    assert "--select needs --out" in capsys.readouterr().err
