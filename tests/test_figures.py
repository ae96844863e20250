"""Figures and report from archives only: every shipped study gives its figures (run here
shrunk: two schemes, at most three values per axis, a short run), the report shows the
summary's table, and the shipped convergence study shows the nominal orders."""

import itertools
import math
import pathlib
import re

import pytest
import yaml
from helpers import CONFIGS, EXACT_FLOW_TOLERANCE, EXACT_FOR_FREE_BODIES, copy_node_tables
from matplotlib.colors import to_rgb

from rbstudy.analysis.plots import all_figures, convergence
from rbstudy.analysis.summary import ERROR_MEASURES, scheme_rows, table_columns
from rbstudy.archive.load import open_results
from rbstudy.cli import main
from rbstudy.inputs.reader import MAX_NAME_BYTES
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.schemes import BUILTIN, SCHEMES, scheme_groups

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
            # and the first scheme listed (splitting among `all`), so that a swept
            # composition keeps a scheme that has it
            composed = ["splitting"] if "run.options.composition" in sweep else []
            listed = [values[0]] if isinstance(values, list) else composed
            sweep[axis] = SHRUNK_SCHEMES + [s for s in listed if s not in SHRUNK_SCHEMES]
        elif axis == "zip":
            sweep[axis] = {dim: {a: _shrink(v) for a, v in group.items()} for dim, group in values.items()}
        else:
            sweep[axis] = _shrink(values)
    interval = study["output"]["interval"]
    study["scene"]["duration"] = min(study["scene"]["duration"], SHRUNK_SAMPLES * interval)
    path = pathlib.Path(folder) / name
    path.write_text(yaml.safe_dump(study))
    copy_node_tables(folder)
    return path


def candidate_figures(ds):
    """The figures a dataset could show by what it stores: a convergence figure per error
    measure stored, when dt is swept; the others by what the dataset holds."""
    names = {"stability_map"}
    if "dt" in ds.dims:
        names.add("work_precision")
        names |= {f"convergence_{key}" for key, measure in ERROR_MEASURES.items() if measure.variable in ds}
    if "energy_error" in ds:
        names.add("invariant_drift")
    if "precession_frequency" in ds and "node_offset" in ds:
        names |= {"benchmark_omega_time", "benchmark_omega_xy", "benchmark_node_path"}
    return names


def drawn(figures, study):
    return {png.stem.removeprefix(f"{study}_") for png in figures.written}


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_study_gives_its_figures(name, tmp_path):
    """Every figure the archive supports is drawn, in both formats and named by study, or
    left out with its reason."""
    done = run_study(load_study(shrunk_config(name, tmp_path)), tmp_path / "out", quiet=True)
    ds = open_results(done.path)
    study = ds.attrs["study"]
    figures = all_figures(ds, tmp_path / "figures", ("png", "svg"))
    candidates, shown, left_out = candidate_figures(ds), drawn(figures, study), set(figures.absent)
    if "benchmark" in left_out:  # the three benchmark figures stand or fall together
        candidates = {n for n in candidates if not n.startswith("benchmark_")} | {"benchmark"}
    assert shown | left_out == candidates and not shown & left_out
    assert all(figures.absent.values())  # every absence says why
    if "dt" in ds.dims:  # a dt sweep always has an order and a cost to show
        assert {"convergence_orientation", "work_precision"} <= shown, shown
    for png in figures.written:
        assert png.name.startswith(f"{study}_")
        # a name of the most bytes a config may give keeps every file name within 255
        assert len(png.with_suffix(".svg").name.encode()) - len(study.encode()) + MAX_NAME_BYTES <= 255
        assert png.stat().st_size > 10_000 and png.with_suffix(".svg").stat().st_size > 10_000


@pytest.mark.slow
def test_the_report_table_shows_every_column_with_the_summary_numbers(tmp_path, capsys):
    done = run_study(load_study(shrunk_config("abaqus_top.yaml", tmp_path)), tmp_path / "out", quiet=True)
    assert main(["report", str(done.path), "--out", str(tmp_path / "report"), "--quiet"]) == 0
    text = (tmp_path / "report" / "report.html").read_text()  # its images: test_report.py
    rows = scheme_rows(open_results(done.path))
    keys = [column.key for column in table_columns(rows)]  # the report shows every column
    table = {
        cells[0]: cells
        for cells in (
            [cell.strip() for cell in re.findall(r"<td[^>]*>([^<]*)</td>", line)]
            for line in text.splitlines()
            if line.startswith("<tr><td>")
        )
    }
    assert set(SHRUNK_SCHEMES) <= set(table)
    for row in rows:  # the table shows the summary's numbers, each in its column
        cells = table[row["scheme"]]
        assert len(cells) == len(keys)
        assert cells[keys.index("failed")] == f"{row['unstable']}/{row['cases']}"
        assert cells[keys.index("order")].startswith(f"{row['order'][0]:.2f}")
    assert "Provenance" in text and "history" in text


@pytest.mark.slow
def test_the_shipped_convergence_study_shows_every_nominal_order(tmp_path):
    done = run_study(load_study(CONFIGS / "convergence_asymmetric.yaml"), tmp_path, quiet=True)
    rows = scheme_rows(open_results(done.path))
    assert {row["scheme"] for row in rows} == set(scheme_groups()["builtin"])
    for row in rows:
        if row["scheme"] in EXACT_FOR_FREE_BODIES:  # round-off at every dt: no order
            assert row["order"] is None and row["error"] <= EXACT_FLOW_TOLERANCE, row
            continue
        low, high = row["order"]
        nominal = SCHEMES[row["scheme"]].order
        assert abs(low - nominal) < 0.25 and abs(high - nominal) < 0.25, row


def test_plot_refuses_a_file_that_is_not_results(tmp_path, capsys):
    bogus = tmp_path / "x.nc"
    bogus.write_text("not netCDF")
    assert main(["plot", str(bogus)]) == 1
    error = capsys.readouterr().err.strip()
    assert "not an rbstudy archive: not a netCDF file" in error and "\n" not in error


@pytest.mark.slow
def test_plot_select_narrows_the_cases(tmp_path, capsys):
    done = run_study(load_study(shrunk_config("abaqus_top.yaml", tmp_path)), tmp_path / "out", quiet=True)
    from rbstudy.commands.results import select_cases as _select

    narrowed = _select(open_results(done.path), ["scheme=hht", "inertia_ratio=2"], "x")
    assert (narrowed.sizes["scheme"], narrowed.sizes["inertia_ratio"]) == (1, 1)
    assert str(narrowed.scheme.values[0]) == "hht" and float(narrowed.inertia_ratio[0]) == 2.0
    capsys.readouterr()
    assert (
        main(
            [
                "plot",
                str(done.path),
                "--out",
                str(tmp_path / "one"),
                "--select",
                "scheme=hht",
                "--select",
                "inertia_ratio=2",
            ]
        )
        == 0
    )
    reported = int(capsys.readouterr().out.split(": ")[1].split()[0])
    assert len(list((tmp_path / "one").glob("*.png"))) == reported > 0
    for bad, message in (
        (["--select", "dt=fast"], "--select dt=fast: dt takes a number"),
        (["--select", "time=1"], "'time' is not a swept dimension"),
    ):
        assert main(["plot", str(done.path), "--out", str(tmp_path / "x"), *bad]) == 1
        assert message in capsys.readouterr().err
    assert main(["plot", str(done.path), "--select", "dt=0.01"]) == 1
    assert "--select needs --out" in capsys.readouterr().err


@pytest.mark.slow
def test_figures_of_two_studies_share_a_folder_and_a_report_sits_beside_its_archive(tmp_path, capsys):
    """`plot a.nc b.nc --out DIR` used to leave 13 of 50 figures: names now carry the study;
    a report goes beside its archive by default and never into another study's folder."""
    paths = [
        run_study(load_study(shrunk_config(name, tmp_path)), tmp_path / "out", quiet=True).path
        for name in ("long_run.yaml", "high_spin.yaml")
    ]
    assert main(["plot", *map(str, paths), "--out", str(tmp_path / "both")]) == 0
    counts = [
        int(line.split(": ")[1].split()[0])
        for line in capsys.readouterr().out.splitlines()
        if "figures (PNG)" in line
    ]
    assert len(list((tmp_path / "both").glob("*.png"))) == sum(counts) > counts[0]
    assert main(["report", str(paths[0])]) == 0
    assert (paths[0].parent / "report" / "report.html").is_file()
    assert main(["report", str(paths[1]), "--out", str(paths[0].parent / "report")]) == 1
    error = capsys.readouterr().err
    assert "holds the report of study 'long_run', not 'high_spin'" in error
    assert main(["plot", str(paths[0]), str(paths[0]), "--out", str(tmp_path / "x")]) == 1
    assert "also study 'long_run'" in capsys.readouterr().err


@pytest.mark.slow
def test_a_convergence_figure_with_nothing_to_show_is_left_out_with_why(tmp_path):
    done = run_study(load_study(shrunk_config("abaqus_top.yaml", tmp_path)), tmp_path / "out", quiet=True)
    ds = open_results(done.path)
    ds["final_orientation_error"][:] = float("nan")  # every case failed
    figures = convergence(ds, tmp_path / "figures")
    assert "convergence_orientation" in figures.absent
    assert "no line shows an asymptotic range" in figures.absent["convergence_orientation"]
    assert not (tmp_path / "figures" / "abaqus_top_convergence_orientation.png").exists()


def test_every_scheme_registers_a_style_of_its_own():
    """rbstudy's own schemes and the engines', each in its file (plug-ins may leave it out)."""
    from rbstudy.schemes import scheme_styles
    from rbstudy.schemes._plugins import ENGINES

    own = [*BUILTIN, *ENGINES]
    styles = scheme_styles(own)
    assert set(styles) == set(own)
    assert len({style.color for style in styles.values()}) == len(own)
    for a, b in (
        ("euler", "leapfrog"),
        ("splitting", "no_squish"),
        ("rk4", "rkmk4"),
        ("mujoco_implicitfast", "mujoco_implicit"),
        ("bullet_multibody", "mujoco_euler"),
        ("bullet_rigidbody", "mujoco_implicit"),
        ("exudyn_rk44", "rkmk4"),
    ):
        # curves that coincide: another marker and another dash, so that both show
        assert styles[a][1:] != styles[b][1:]
        assert styles[a].dash != styles[b].dash
    # two lines of one dash are told apart by their colours: exudyn_rk44's crimson and rk4's
    # red, both solid, were 0.10 apart and read as one scheme
    for (a, style_a), (b, style_b) in itertools.combinations(styles.items(), 2):
        if style_a.dash == style_b.dash:
            distance = math.dist(to_rgb(style_a.color), to_rgb(style_b.color))
            assert distance >= 0.2, (a, b, distance)


def test_a_scheme_without_a_style_gets_one_no_other_line_of_the_study_wears():
    """A plug-in's lines took a style chosen by its name's letters among eight, which could be
    euler's own or another plug-in's."""
    from rbstudy.analysis.plots import line_styles
    from rbstudy.schemes import scheme_styles

    registered = scheme_styles(["euler", "leapfrog", "rk4"])
    plugins = [f"plugin_{k}" for k in range(30)]
    styles = line_styles(["euler", "leapfrog", "rk4", *plugins], registered)
    assert all(styles[name] == tuple(registered[name]) for name in registered)
    assert len({style[:2] for style in styles.values()}) == len(styles)  # colour and marker
    colours = {style.color for style in registered.values()}
    # while colours are left, a plug-in takes one no registered line wears
    assert not colours & {styles[name][0] for name in plugins[:5]}
    # and the same study gives a plug-in the same style in every figure, whatever the order
    assert (
        line_styles(["rk4", "plugin_0"], registered)["plugin_0"]
        == line_styles(["plugin_0", "rk4"], registered)["plugin_0"]
    )


def test_an_exact_zero_is_on_the_floor_with_its_own_mark_and_a_failure_a_gap():
    """Zeros were drawn as gaps in their line, the mark of a failed case."""
    import matplotlib.pyplot as plt
    import numpy as np

    from rbstudy.analysis.figure_marks import EXACT_ZERO_LABEL, zero_entry
    from rbstudy.analysis.plots import plot_with_zeros, zero_floor

    errors = np.array([3e-4, 0.0, 1e-5, np.nan, 2e-6])  # a zero, and a failed case
    floor = zero_floor(errors)
    assert floor == 10**-7.5  # between the tick labels 1e-8 and 1e-7, below every value
    fig, ax = plt.subplots()
    style = dict(
        color="k", marker="o", linestyle="-", markersize=4, markerfacecolor="k", zorder=2, linewidth=1
    )
    plot_with_zeros(ax, np.arange(5.0), errors, floor, "x", style)
    line, zeros = ax.lines
    drawn = line.get_ydata()
    assert drawn[1] == floor and np.isfinite(drawn[:3]).all()  # the line runs down to the zero
    assert np.isnan(drawn[3])  # only the failure is a gap
    assert 1 not in line.get_markevery()  # the zero wears no scheme marker ...
    assert list(zeros.get_xdata()) == [1.0] and list(zeros.get_ydata()) == [floor]
    assert zeros.get_marker() not in {m for m in "o^sDvPX*<>hdp8Hx"}  # ... but its own
    ((handle,), label), *rest = zero_entry(fig)
    assert label == EXACT_ZERO_LABEL and handle.get_marker() == zeros.get_marker() and not rest
    plt.close(fig)


@pytest.fixture
def drawn_figures(monkeypatch):
    """The matplotlib figures the plot functions draw, kept open instead of saved."""
    import matplotlib.pyplot as plt

    from rbstudy.analysis import figure_frame

    kept = {}

    def keep(fig, folder, ds, name, formats):
        figure_frame.log_labels(fig)  # what `save` does before it writes
        kept[name] = fig
        return pathlib.Path(folder) / f"{name}.png"

    monkeypatch.setattr(figure_frame, "save", keep)
    yield kept
    plt.close("all")


@pytest.mark.slow
def test_the_drawn_lines_wear_their_scheme_styles_and_legends_sit_outside(tmp_path, drawn_figures):
    import matplotlib.colors as colors

    from rbstudy.analysis.figure_marks import EXACT_ZERO_LABEL
    from rbstudy.analysis.plots import ZERO_LABEL
    from rbstudy.commands.common import styles_of as _styles_of

    done = run_study(load_study(shrunk_config("abaqus_top.yaml", tmp_path)), tmp_path / "out", quiet=True)
    ds = open_results(done.path)
    styles = _styles_of(ds)  # what `rbstudy plot` reads from the registry
    assert styles == {name: SCHEMES[name].style for name in SHRUNK_SCHEMES}
    all_figures(ds, tmp_path / "figures", styles=styles)
    fig = drawn_figures["convergence_energy"]
    fig.canvas.draw()
    panels = [ax for ax in fig.axes if ax.get_visible()]
    (legend,) = fig.legends
    # the figure's one legend lies right of every panel, not over one
    assert legend.get_window_extent().x0 >= max(ax.get_window_extent().x1 for ax in panels)
    styled = set()
    for ax in panels:
        assert ax.get_legend() is None
        for line in ax.get_lines():
            scheme = next((s for s in styles if colors.same_color(line.get_color(), styles[s].color)), None)
            if scheme is not None and line.get_marker() == styles[scheme].marker:
                styled.add(scheme)
    assert styled == set(SHRUNK_SCHEMES)  # every scheme drawn, each in its own style
    named = {text.get_text().split(" (")[0] for text in legend.get_texts()}
    assert named == set(SHRUNK_SCHEMES) | {EXACT_ZERO_LABEL.split(" (")[0]}  # hht's energy: exactly 0
    texts = [t.get_text() for ax in panels for t in ax.texts]
    assert ZERO_LABEL in texts  # hht keeps the energy exactly: drawn on the floor
    bench = drawn_figures["benchmark_omega_time"]
    bench.canvas.draw()
    w_z = bench.axes[2]  # w_z varies by 1e-7 around 6.28691: it read "1e-7+6.28691"
    assert w_z.yaxis.get_major_formatter().get_offset() == ""
    assert all("6.2869" in tick.get_text() for tick in w_z.get_yticklabels() if tick.get_text())
    case_line = bench.axes[0].get_lines()[0]
    assert case_line.get_label().startswith("hht")
    assert colors.same_color(case_line.get_color(), styles["hht"].color)


def test_plot_and_report_name_what_a_file_is_or_lacks(tmp_path, capsys):
    import numpy as np
    import xarray as xr

    done = run_study(
        load_study(shrunk_config("long_run.yaml", tmp_path)), tmp_path / "out", quiet=True, keep_parts=True
    )
    part = next((done.path.parent / "parts").glob("*.npz"))
    foreign = tmp_path / "foreign.nc"
    xr.Dataset({"status": ("x", np.zeros(3)), "omega_body": ("x", np.ones(3))}).to_netcdf(foreign)
    stripped = tmp_path / "stripped.nc"
    open_results(done.path).drop_vars(["accuracy", "run_time"]).to_netcdf(stripped)
    for path, message in (
        (part, "is one batch's part file, not a study's archive"),
        (foreign, "not an rbstudy archive: no study attribute; it holds status, omega_body"),
        (stripped, "not an rbstudy archive: it lacks accuracy, run_time (written by rbstudy "),
    ):
        for verb in (
            ["plot", str(path), "--out", str(tmp_path / "figs")],
            ["report", str(path), "--out", str(tmp_path / "rep")],
        ):
            assert main(verb) == 1
            error = capsys.readouterr().err.strip()
            assert "\n" not in error and f"{path}: {message}" in error, error


@pytest.mark.slow
def test_figures_drawn_in_forked_processes_are_those_drawn_in_one(tmp_path):
    """`rbstudy plot` draws in as many processes as it has cores (2 in CI); the files are
    the same, byte for byte, in the same order, with the same figures left out and why."""
    import subprocess
    import sys

    done = run_study(load_study(shrunk_config("abaqus_top.yaml", tmp_path)), tmp_path / "out", quiet=True)
    from rbstudy.schemes import scheme_styles

    styles = scheme_styles(SHRUNK_SCHEMES)  # as the command line reads them
    serial = all_figures(open_results(done.path), tmp_path / "one", styles=styles)
    forked = all_figures(open_results(done.path), tmp_path / "two", processes=2, styles=styles)
    assert [path.name for path in forked.written] == [path.name for path in serial.written]
    assert forked.absent == serial.absent
    for one, two in zip(serial.written, forked.written, strict=True):
        assert one.read_bytes() == two.read_bytes(), one.name
    command = subprocess.run(
        [sys.executable, "-m", "rbstudy", "plot", str(done.path), "--out", str(tmp_path / "cli")],
        capture_output=True,
        text=True,
        check=True,
    )
    assert f"{len(serial.written)} figures (PNG)" in command.stdout
    for one in serial.written:
        assert (tmp_path / "cli" / one.name).read_bytes() == one.read_bytes(), one.name


@pytest.fixture(scope="module")
def top_with_twins(tmp_path_factory):
    """The shrunk Abaqus top with euler and leapfrog, whose errors coincide on it."""
    root = tmp_path_factory.mktemp("twins")
    path = shrunk_config("abaqus_top.yaml", root)
    study = yaml.safe_load(path.read_text())
    study["sweep"]["scheme"] = ["euler", "leapfrog", "hht"]
    path.write_text(yaml.safe_dump(study))
    return open_results(run_study(load_study(path), root / "out", quiet=True).path)


@pytest.mark.slow
def test_one_legend_per_figure_names_coinciding_linestogether(top_with_twins, tmp_path, drawn_figures):
    """It was a 9-entry legend in each of 4 panels, and up to 5 of 9 lines hidden."""
    import numpy as np

    all_figures(top_with_twins, tmp_path)
    for name, fig in drawn_figures.items():
        in_panels = sum(ax.get_legend() is not None for ax in fig.axes)
        assert len(fig.legends) + in_panels == 1, name
    fig = drawn_figures["convergence_precession"]
    texts = [text.get_text() for text in fig.legends[0].get_texts()]
    assert texts[0].startswith("euler = leapfrog to 3 digits (order 2.00"), texts
    assert texts[1].startswith("hht (order 2.00") and len(texts) == 2, texts
    for ax in [ax for ax in fig.axes if ax.get_visible()]:  # both twins drawn, their
        twins = [
            line
            for line in ax.get_lines()  # markers on alternate points
            if line.get_markevery() is not None
        ]
        assert [line.get_markevery() for line in twins] == [(0, 2), (1, 2)]
        assert np.allclose(twins[0].get_ydata(), twins[1].get_ydata(), rtol=1e-3)
        assert twins[0].get_markerfacecolor() == "none" != twins[1].get_markerfacecolor()
        assert twins[0].get_zorder() < twins[1].get_zorder()


@pytest.mark.slow
def test_slope_guides_cross_no_line_and_log_ticks_read_powers_of_ten(top_with_twins, tmp_path, drawn_figures):
    import matplotlib.colors as colors
    import numpy as np

    all_figures(top_with_twins, tmp_path)
    fig = drawn_figures["convergence_orientation"]
    fig.canvas.draw()
    for ax in [ax for ax in fig.axes if ax.get_visible()]:
        guides = [
            line
            for line in ax.get_lines()
            if line.get_linestyle() == ":" and colors.same_color(line.get_color(), "0.6")
        ]
        data = [
            line
            for line in ax.get_lines()
            if line.get_linestyle() != "None" and line not in guides and line.get_xdata().size > 2
        ]
        assert len(guides) == 3 and data  # orders 1, 2 and 4
        for guide in guides:
            x, y = np.log10(guide.get_xdata()), np.log10(guide.get_ydata())
            for line in data:
                xs, ys = np.log10(line.get_xdata()), np.log10(line.get_ydata())
                gaps = np.interp(x, xs[::-1], ys[::-1]) - y if xs[0] > xs[-1] else np.interp(x, xs, ys) - y
                gaps = gaps[np.isfinite(gaps)]
                # one side of the line all along (straight between steps on log axes), and
                # clear of it: it used to start on the median error, a point of some line
                assert np.all(gaps > 0.1) or np.all(gaps < -0.1), line.get_label()
        labels = [tick.get_text() for tick in ax.get_yticklabels() if tick.get_text()]
        assert labels and all(label.startswith("$") and "10^{" in label for label in labels)


@pytest.mark.slow
def test_the_drift_figure_names_its_case_once_in_its_title(top_with_twins, tmp_path, drawn_figures):
    from rbstudy.analysis.figure_marks import EXACT_ZERO_LABEL

    all_figures(top_with_twins, tmp_path)
    fig = drawn_figures["invariant_drift"]
    title = fig._suptitle.get_text().replace("\n", " ")
    ratio = float(top_with_twins["inertia_ratio"][0])
    assert (
        f"case: inertia_ratio = {ratio:g}, dt = 0.01 s (the first value of each swept "
        "axis; the largest dt at which every scheme ran stable)"
    ) in title
    (legend,) = fig.legends
    # and the exact-zero mark: hht keeps the energy exactly
    assert [text.get_text() for text in legend.get_texts()] == ["euler", "leapfrog", "hht", EXACT_ZERO_LABEL]


def test_one_swept_axis_gives_a_strip_chart_and_an_all_accurate_map_is_left_out(tmp_path, drawn_figures):
    """high_spin (spin only) drew 9 panels of one diagonal."""
    from rbstudy.analysis.plots import stability_map

    ds = open_results(
        run_study(load_study(shrunk_config("high_spin.yaml", tmp_path)), tmp_path / "out", quiet=True).path
    )
    stability_map(ds, tmp_path / "figures")
    fig = drawn_figures["stability_map"]
    (ax,) = fig.axes
    assert [tick.get_text() for tick in ax.get_yticklabels()] == SHRUNK_SCHEMES
    assert ax.get_xscale() == "log" and ax.get_xlabel() == "dt |w0| (rad)"
    # each scheme's cases in its row, at their dt |w0|
    points = sorted((float(y), float(x)) for c in ax.collections for x, y in c.get_offsets())
    assert len(points) == len(SHRUNK_SCHEMES) * ds.sizes["spin"]
    assert {y for y, _ in points} == set(range(len(SHRUNK_SCHEMES)))
    texts = [text.get_text() for text in fig.legends[0].get_texts()]
    assert "accurate" in texts and "failed (unstable or not converged)" in texts
    drawn_figures.clear()
    ds["status"][:] = 0
    ds["accuracy"][:] = 0
    figures = stability_map(ds, tmp_path / "figures")
    assert not figures.written and not drawn_figures
    assert figures.absent["stability_map"].startswith("every case is accurate (dt |w0| up to ")


def test_lines_coincide_when_every_point_agrees_to_three_digits():
    """Two lines failed at every dt have nothing to agree on: each stays its own entry."""
    import numpy as np

    from rbstudy.analysis.overlaps import coincident

    nan = float("nan")
    errors = np.array(
        [
            [1e-3, 2e-6, nan],
            [1.0004e-3, 2.0008e-6, nan],
            [nan, nan, nan],
            [nan, nan, nan],
            [1e-3, 2.01e-6, nan],
        ]
    )
    assert coincident(errors) == [[0, 1], [2], [3], [4]]


@pytest.mark.parametrize("span", [(0.0116, 0.046), (0.0056, 0.028), (1.02, 1.4), (1e-15, 1e-1)])
def test_every_log_tick_reads_as_its_value(span):
    """Under a decade matplotlib fell back to linear ticks at 0.015, 0.025, ..., which the
    labels rounded to "2x10^-2" twice: a tick must read as its own value (to 3 digits)."""
    import matplotlib.pyplot as plt

    from rbstudy.analysis.figure_frame import log_labels

    fig, ax = plt.subplots()
    ax.set_xscale("log")
    ax.set_xlim(*span)
    log_labels(fig)
    fig.canvas.draw()
    shown = [(tick.get_loc(), tick.label1.get_text()) for tick in ax.xaxis.get_major_ticks()]
    shown = [(at, text) for at, text in shown if span[0] <= at <= span[1]]
    plt.close(fig)
    assert len(shown) >= 2
    for at, text in shown:
        match = re.fullmatch(r"\$(?:([\d.]+)\\times)?10\^\{(-?\d+)\}\$", text)
        value = float(match[1] or 1) * 10.0 ** int(match[2])
        assert value == pytest.approx(at, rel=5e-3), (at, text)


@pytest.mark.parametrize("title", ["t" * 10**6, "word " * 200_000, "a\n" * 1000])
def test_a_long_title_from_an_archive_heads_a_figure_in_two_lines_cut_with_an_ellipsis(title):
    """An archive made elsewhere may carry any title: a megabyte of one took `plot` 171 s
    and covered every panel."""
    import time

    import matplotlib.pyplot as plt
    import xarray as xr

    from rbstudy.analysis import figure_text

    fig = plt.figure(figsize=(5.4, 4.2))
    started = time.perf_counter()
    figure_text.title(fig, xr.Dataset(attrs={"title": title}), "what it shows")
    drawn = fig._suptitle.get_text().split("\n")
    fig.canvas.draw()
    plt.close(fig)
    assert time.perf_counter() - started < 1.0
    assert drawn[-1] == "what it shows" and len(drawn) == figure_text.TITLE_LINES + 1
    assert drawn[-2].endswith("\u2026") and all(len(line) < 120 for line in drawn)


def test_a_title_with_a_long_run_of_spaces_is_drawn_whole():
    """A run of white space wider than the title's room left fewer lines than it fills and
    failed (IndexError) in plot and report; its words are drawn, the run one space."""
    import matplotlib.pyplot as plt
    import xarray as xr

    from rbstudy.analysis.figure_text import title

    fig = plt.figure(figsize=(5.4, 4.2))
    title(fig, xr.Dataset(attrs={"title": "a" + " " * 600 + "b"}), "what it shows")
    drawn = fig._suptitle.get_text().split("\n")
    plt.close(fig)
    assert drawn == ["a b", "what it shows"]


def _with_a_failed_value(ds, scheme):
    """``ds`` with ``scheme`` failed at every dt of the first inertia ratio (as an archive
    holds a blow-up: status 1, no error)."""
    import numpy as np

    ds = ds.copy(deep=True)
    at = {"scheme": scheme, "inertia_ratio": ds["inertia_ratio"].values[0]}
    ds["status"].loc[at] = 1
    for name, variable in ds.data_vars.items():
        if {"scheme", "inertia_ratio"} <= set(variable.dims) and variable.dtype.kind == "f":
            if name not in ("run_time",):
                ds[name].loc[at] = np.nan
    return ds


@pytest.mark.slow
def test_every_scheme_keeps_a_line_where_an_axis_is_too_long_for_panels(
    top_with_twins, tmp_path, drawn_figures, monkeypatch
):
    """stiff_inertia's figures showed the worst case over its 17 inertia ratios with a
    failure kept as NaN: 6 of 9 schemes had no line, 4 of 6 convergence figures were left
    out. A scheme that failed at one value still shows where it did not, and its order is
    fitted value by value."""
    import numpy as np

    from rbstudy.analysis import figure_lines

    monkeypatch.setattr(figure_lines, "MAX_FACETS", 1)  # the three ratios become one reduced axis
    from rbstudy.commands.common import styles_of as _styles_of

    ds = _with_a_failed_value(top_with_twins, "hht")
    figures = all_figures(ds, tmp_path, styles=_styles_of(ds))
    assert {"convergence_orientation", "work_precision"} <= drawn(figures, ds.attrs["study"])
    for name in ("convergence_orientation", "work_precision"):
        (ax,) = [ax for ax in drawn_figures[name].axes if ax.get_visible()]
        colours = {
            to_rgb(line.get_color())
            for line in ax.get_lines()
            if np.isfinite(np.asarray(line.get_ydata(), dtype=float)).sum() > 1
        }
        for scheme in ds["scheme"].values:
            assert to_rgb(SCHEMES[str(scheme)].style.color) in colours, (name, scheme)
    legend = [
        t.get_text().replace("\n", " ")
        for t in drawn_figures["convergence_orientation"].legends[0].get_texts()
    ]
    hht = next(text for text in legend if text.startswith("hht"))
    steps, ratios = ds.sizes["dt"], ds.sizes["inertia_ratio"]
    assert (
        f"of {ratios} values of inertia_ratio" in hht
        and f"no value in {steps} of {steps * ratios} cases" in hht
    )
    # and the caption, as the figure: hht's worst error where it finished, its failure counted
    from rbstudy.analysis.findings import findings
    from rbstudy.analysis.report import captions

    rows = scheme_rows(ds)
    text, _ = captions(ds, ["convergence_energy"], rows, findings(ds, rows))["convergence_energy"]
    assert re.search(rf"hht \S+ \(1 of {ratios} cases failed\)", text), text


@pytest.mark.slow
def test_the_stability_caption_says_what_the_map_draws(top_with_twins):
    """stiff_inertia's caption called rk4 "accurate in every case" (the table's dt |w0|
    limits count physical bodies only) beside a map of its failures at I3/I1 >= 100."""
    import numpy as np

    from rbstudy.analysis.findings import findings
    from rbstudy.analysis.report import captions

    ds = top_with_twins.copy(deep=True)
    unphysical = {"inertia_ratio": ds["inertia_ratio"].values[-1]}
    ds["physical_body"].loc[unphysical] = 0
    ds["accuracy"].loc[{"scheme": "hht", **unphysical}] = 1  # inaccurate there only
    rows = scheme_rows(ds)
    text, _ = captions(ds, ["stability_map"], rows, findings(ds, rows))["stability_map"]
    accurate = [
        str(scheme)
        for scheme in ds["scheme"].values
        if bool(((ds["accuracy"] == 0) & (ds["status"] == 0)).sel(scheme=scheme).all())
    ]
    said = re.search(r"Accurate in every case: ([^.]*)\.", text)
    named = re.split(r", | and ", said[1]) if said else []
    assert named == accurate, text
    hht = ds["accuracy"].sel(scheme="hht")
    assert f"hht {int((hht == 0).sum())} of {hht.size} accurate, {int((hht == 1).sum())} inaccurate" in text
    assert np.any(hht == 1)


@pytest.mark.slow
def test_lines_on_top_of_each_other_are_named_in_the_drift_figure(top_with_twins, tmp_path, drawn_figures):
    """invariant_drift named no overlap: hht's and midpoint's exact energies lay on the
    floor as one line. Each panel names the lines it draws on top of each other."""
    import numpy as np

    from rbstudy.analysis.summary import agree

    all_figures(top_with_twins, tmp_path)
    fig = drawn_figures["invariant_drift"]
    for ax in [ax for ax in fig.axes if ax.get_visible()]:
        lines = {}  # colour -> the drawn values of its scheme's line
        for line in ax.get_lines():
            if line.get_gid() is None and np.asarray(line.get_xdata()).size > 2:
                lines.setdefault(line.get_color(), np.asarray(line.get_ydata(), dtype=float))
        values = list(lines.values())
        overlapping = any(agree(a, b) for i, a in enumerate(values) for b in values[i + 1 :])
        title = ax.get_title().replace("\n", " ")
        assert overlapping == title.startswith("on top of each other:"), title
    title = fig.axes[0].get_title().replace("\n", " ")
    assert "euler = leapfrog to 3 digits" in title  # their energies agree on the top


@pytest.mark.slow
def test_lines_on_top_of_each_other_in_one_panel_only_are_named_over_it(
    top_with_twins, tmp_path, drawn_figures
):
    """The legend names the lines that coincide in every case; two that coincide at one
    inertia ratio only (as rk4 and rkmk4's errors nearly do at I3/I1 = 0.1 and differ 3-76x
    at the others) lay on top of each other in that panel with no note. The panel names
    them, and no pair the legend names."""
    from rbstudy.analysis.summary import agree

    ds = top_with_twins.copy(deep=True)
    variable = ERROR_MEASURES["precession"].variable
    apart = {"scheme": "leapfrog", "inertia_ratio": ds["inertia_ratio"].values[1:]}
    ds[variable].loc[apart] = 1.1 * ds[variable].loc[apart]  # euler's only at the first ratio
    convergence(ds, tmp_path, measures=("precession",))
    fig = drawn_figures["convergence_precession"]
    legend = [text.get_text().replace("\n", " ") for text in fig.legends[0].get_texts()]
    assert not any(" = " in text for text in legend), legend  # apart over the whole study
    euler, leapfrog = (abs(ds[variable].sel(scheme=s)) for s in ("euler", "leapfrog"))
    panels = [ax for ax in fig.axes if ax.get_visible()]
    for ax, ratio in zip(panels, ds["inertia_ratio"].values, strict=True):
        together = agree(euler.sel(inertia_ratio=ratio).values, leapfrog.sel(inertia_ratio=ratio).values)
        title = ax.get_title().replace("\n", " ")
        assert together == (ratio == ds["inertia_ratio"].values[0]), ratio
        assert ("on top of each other: euler = leapfrog to 3 digits" in title) == together, title
    # a pair the legend names is not named again over a panel: euler and leapfrog coincide
    # everywhere in the archive as run, and their panels say nothing
    drawn_figures.clear()
    convergence(top_with_twins, tmp_path, measures=("precession",))
    fig = drawn_figures["convergence_precession"]
    assert fig.legends[0].get_texts()[0].get_text().startswith("euler = leapfrog to 3 digits")
    titles = [ax.get_title() for ax in fig.axes]
    assert not any("on top of each other" in title for title in titles), titles


def test_a_panel_names_only_the_lines_its_legend_keeps_apart():
    """Lines coinciding in a panel are named there by their legend groups' first lines:
    never a pair the legend already names."""
    import numpy as np

    from rbstudy.analysis.overlaps import panel_overlaps

    same, other = np.array([1e-3, 1e-5, 1e-7]), np.array([2e-3, 2e-5, 2e-7])
    names = ["rk4", "rkmk4", "exudyn_rk44", "euler"]
    # the legend names rk4 = rkmk4; here exudyn_rk44 lies on them too, euler apart
    assert panel_overlaps(names, [same, same, same, other], [[0, 1], [2], [3]]) == [
        "rk4 = exudyn_rk44 to 3 digits"
    ]
    assert panel_overlaps(names, [same, same, other, other], [[0, 1], [2], [3]]) == [
        "exudyn_rk44 = euler to 3 digits"
    ]
    assert panel_overlaps(names, [same, same, other, 3 * other], [[0, 1], [2], [3]]) == []
    # hht's and midpoint's energies, exactly 0 at every dt, read as such, not "to 3 digits"
    zeros = np.zeros(3)
    assert panel_overlaps(["hht", "midpoint"], [zeros, zeros], [[0], [1]], 1e-15) == [
        "hht = midpoint (exactly 0 throughout)"
    ]


def _log_panel(decades=16):
    """A 5 x 3.5 inch log-log panel over ``decades`` decades of y, its limits set; and its
    height in points, measured by matplotlib."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(1e-3, 1e-2)
    ax.set_ylim(10.0**-decades, 1.0)
    fig.canvas.draw()
    return fig, ax, ax.get_window_extent().height / fig.dpi * 72


def test_lines_the_eye_cannot_part_are_named_with_how_far_apart_they_are():
    """euler's and leapfrog's worst errors over stiff_inertia's ratios, 0.3-1.4% apart, drew
    one line with no note. A line whose every point lies within a line's width (2 pt) of
    another's, on the page as drawn, is named with it; 1 pt apart is near, 3 pt is not; a
    gap where the other has a value parts them; lines the data already names as one are
    named once."""
    import matplotlib.pyplot as plt
    import numpy as np

    from rbstudy.analysis.overlaps import near_lines, panel_overlaps

    fig, ax, height = _log_panel()
    dts = np.array([1.25e-3, 2.5e-3, 5e-3, 1e-2])
    euler = np.array([2.6e-2, 2.6e-1, 1.34e-2, 2.76e-2])
    leapfrog = euler * np.array([1.003, 1.014, 0.997, 0.995])
    one_pt, three_pt = 10.0 ** (16 / height), 10.0 ** (3 * 16 / height)  # factors in y
    curves = [(dts, euler), (dts, leapfrog), (dts, euler * one_pt), (dts, euler * three_pt)]
    names = ["euler", "leapfrog", "one_pt", "three_pt"]
    assert near_lines(ax, names, curves) == [f"euler ≈ leapfrog ≈ one_pt (within {1 - 1 / one_pt:.1%})"]
    assert near_lines(ax, names[:2], curves[:2]) == ["euler ≈ leapfrog (within 1.4%)"]
    gapped = np.where([True, True, False, True], leapfrog, np.nan)
    assert near_lines(ax, names[:2], [(dts, euler), (dts, gapped)]) == []
    # an exact pair (the legend's rk4 = rkmk4) and a near pair, each named once
    rk4 = np.array([4.1e-4, 4.0e-4, 1.06e-3, 1.27e-3])
    values = [rk4, rk4, euler, leapfrog]
    notes = panel_overlaps(
        ["rk4", "rkmk4", "euler", "leapfrog"],
        values,
        [[0], [1], [2], [3]],
        ax=ax,
        curves=[(dts, v) for v in values],
    )
    assert notes == ["rk4 = rkmk4 to 3 digits", "euler ≈ leapfrog (within 1.4%)"]
    plt.close(fig)


def test_lines_apart_only_at_round_off_coincide():
    """rk4 and rkmk4 differed by 2% at one precession error of 2.6e-14 rad and were drawn as
    one line with no note: below the measure's round-off floor a figure cannot part them."""
    import numpy as np

    from rbstudy.analysis.overlaps import coincident, together

    rows = [np.array([4.6e-13, 2.6e-14, 1e-8]), np.array([4.6e-13, 2.55e-14, 1e-8])]
    assert coincident(rows, 1e-13) == [[0, 1]]
    assert coincident(rows) == [[0], [1]]  # exact agreement still asked above the floor
    assert together(["rk4", "rkmk4"], rows, 1e-13) == "rk4 = rkmk4 to 3 digits above round-off (1e-13)"


def _data_points(ax, labels):
    """Display points of the data lines of ``ax`` (sampled along their segments, and their
    markers): what a label must not cover."""
    import numpy as np

    points = []
    for line in ax.get_lines():
        if line.get_linestyle() == ":" and to_rgb(line.get_color()) == to_rgb("0.6"):
            continue  # a slope guide
        data = np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float)
        xy = line.get_transform().transform(data)
        finite = np.isfinite(xy).all(axis=1)
        if line.get_linestyle() != "None":
            both = finite[:-1] & finite[1:]
            for t in np.linspace(0, 1, 200):
                points.append((xy[:-1] + t * (xy[1:] - xy[:-1]))[both])
        if line.get_marker() not in ("None", "", None):
            points.append(xy[finite])
    return np.concatenate(points)


@pytest.mark.slow
def test_slope_labels_cover_no_line(top_with_twins, tmp_path, drawn_figures):
    """The slope guides kept clear of the lines, their labels did not: "order 2" sat on the
    data in the README's own figure."""

    all_figures(top_with_twins, tmp_path)
    for name in ("convergence_orientation", "convergence_precession", "convergence_energy"):
        fig = drawn_figures[name]
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        for ax in [ax for ax in fig.axes if ax.get_visible()]:
            labels = [t for t in ax.texts if t.get_text().startswith("order ")]
            assert labels
            points = _data_points(ax, labels)
            for label in labels:
                box = label.get_window_extent(renderer)
                inside = (
                    (points[:, 0] > box.x0)
                    & (points[:, 0] < box.x1)
                    & (points[:, 1] > box.y0)
                    & (points[:, 1] < box.y1)
                )
                assert not inside.any(), (name, label.get_text())


@pytest.mark.slow
def test_the_work_precision_figure_draws_the_bound_and_the_recommended_point(
    top_with_twins, tmp_path, drawn_figures
):
    import numpy as np

    from rbstudy.analysis.findings import findings

    all_figures(top_with_twins, tmp_path)
    fig = drawn_figures["work_precision"]
    bound = top_with_twins.attrs["accuracy_bound"]
    answer = next(f for f in findings(top_with_twins) if f.kind == "recommendation")
    scheme, dt = answer.cases[0]["scheme"], answer.cases[0]["dt"]
    error = top_with_twins["final_orientation_error"].sel(scheme=scheme, dt=dt)
    # the cost the findings rank by: the steps at the scheme's calibrated seconds a step
    case = top_with_twins.sel(scheme=scheme, dt=dt)
    seconds = case["n_steps"] * case["step_seconds"]
    for ax in [ax for ax in fig.axes if ax.get_visible()]:
        ratio = float(ax.get_title().split("= ")[1])
        vertical = [
            line for line in ax.get_lines() if np.allclose(np.asarray(line.get_xdata(), dtype=float), bound)
        ]
        assert vertical, "no accuracy bound line"
        (star,) = [line for line in ax.get_lines() if line.get_marker() == "*"]
        assert star.get_xdata()[0] == pytest.approx(float(error.sel(inertia_ratio=ratio)))
        assert star.get_ydata()[0] == pytest.approx(float(seconds.sel(inertia_ratio=ratio)))
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    tied = [other["scheme"] for other in answer.numbers["equal_cost"]]
    named = " or ".join([", ".join([scheme, *tied][:-1]), [scheme, *tied][-1]]) if tied else scheme
    assert f"recommended: {named}{', equal cost,' if tied else ''} at dt = {dt:g} s" in texts
    assert any(text.startswith(f"accuracy bound {bound:g} rad") for text in texts)
