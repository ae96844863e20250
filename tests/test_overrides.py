"""`--set KEY=VALUE` on sweep and validate: applied to the config's mapping before it is
validated, refused in one line as the file would be, recorded in the archive, and another
state of the same study for the resume rules."""

import re

import pytest
import yaml
from helpers import write_study

from rbstudy.archive.load import open_results
from rbstudy.archive.owner import OWNER
from rbstudy.cli import main
from rbstudy.pipeline.config import load_study

# A study of two schemes, one with the option `alpha` (hht) and one without (rk4), at two
# time steps: four batches, two of which an override of alpha changes.
SWEEP = {"scheme": ["rk4", "hht"], "dt": {"halving": 0.01, "count": 2}}


def _sweep(config, out, *argv):
    """Sweep ``config`` into ``out`` quietly with the extra arguments ``argv``."""
    assert main(["sweep", str(config), "--out", str(out), "--quiet", *argv]) == 0


def _said(capsys):
    return " ".join(capsys.readouterr().out.split())  # status lines break at 100 columns


@pytest.mark.slow
def test_an_override_is_applied_and_recorded_in_the_archive(tmp_path, capsys):
    config = write_study(tmp_path, name="top", sweep=SWEEP)
    _sweep(
        config,
        tmp_path / "out",
        "--set",
        "sweep.dt.count=3",
        "--set",
        "run.options.alpha=-0.1",
        "--set",
        "title=Three steps",
    )
    ds = open_results(tmp_path / "out" / "top" / "top.nc")
    assert ds.sizes["dt"] == 3 and ds.attrs["title"] == "Three steps"
    assert ds.attrs["overrides"] == "sweep.dt.count=3\nrun.options.alpha=-0.1\ntitle=Three steps"
    stored = ds.attrs["config"]
    assert stored.startswith("# rbstudy: the config file's values with these applied")
    assert "#   --set run.options.alpha=-0.1\n" in stored
    values = yaml.safe_load(stored)  # the stored text is a config that makes this study
    assert values["sweep"]["dt"] == {"halving": 0.01, "count": 3}
    assert values["run"] == {"scheme": "rk4", "dt": 0.01, "options": {"alpha": -0.1}}
    rerun = tmp_path / "stored.yaml"
    rerun.write_text(stored)
    assert (
        load_study(rerun).batches
        == load_study(config, ["sweep.dt.count=3", "run.options.alpha=-0.1"]).batches
    )
    resolved = yaml.safe_load((tmp_path / "out" / "top" / "study.yaml").read_text())
    assert resolved["run"]["options"] == {"alpha": -0.1} and resolved["cases"] == 6
    # without overrides the archive stores the file's text itself
    _sweep(config, tmp_path / "plain")
    plain = open_results(tmp_path / "plain" / "top" / "top.nc")
    assert plain.attrs["config"] == config.read_text() and plain.attrs["overrides"] == ""
    # summary and report read an overridden archive as any other
    assert main(["summary", str(tmp_path / "out" / "top" / "top.nc")]) == 0
    assert "rk4" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("assignment", "path", "value"),
    [
        ("run.dt=5e-3", ("run", "dt"), 0.005),
        ("run.scheme=hht", ("run", "scheme"), "hht"),
        ("scene.body.inertia.2=1.5", ("scene", "body", "inertia", 2), 1.5),
        ("scene.body.inertia=[2, 2, 3]", ("scene", "body", "inertia"), [2, 2, 3]),
        ("output.accuracy_bound=0.1", ("output", "accuracy_bound"), 0.1),  # not in the file
        ("sweep.scene.body.mass=[1, 2]", ("sweep", "scene.body.mass"), [1, 2]),  # a new axis
        ("sweep.dt=[0.01]", ("sweep", "dt"), [0.01]),
    ],
)
def test_values_are_read_as_yaml_and_missing_keys_the_study_knows_are_created(
    tmp_path, assignment, path, value
):
    config = write_study(tmp_path, run={"scheme": "rk4", "dt": 0.01}, sweep={"dt": [0.01, 0.005]})
    file_text = config.read_text()
    study = load_study(config, [assignment])
    node = yaml.safe_load(study.archived_text)
    for key in path:
        node = node[key]
    assert node == value
    assert config.read_text() == file_text and study.text == file_text  # the file is its own


def test_an_alias_of_the_file_keeps_its_value_where_it_is_not_overridden(tmp_path):
    config = tmp_path / "alias.yaml"
    config.write_text(
        "name: alias\nscene:\n  body: {mass: 1.0, inertia: &m [1.0, 1.0, 2.0]}\n"
        "  initial: {angular_velocity: {body: [0.25, 0.0, 6.0]}}\n  nodes: {tip: *m}\n"
        "  duration: 0.5\noutput: {interval: 0.01}\nrun: {scheme: rk4, dt: 0.01}\n"
    )
    study = load_study(config, ["scene.body.inertia.2=1.5"])
    assert study.base["scene"]["body"]["inertia"] == [1.0, 1.0, 1.5]
    assert study.base["scene"]["nodes"]["tip"] == [1.0, 1.0, 2.0]  # the alias: the file's


def test_an_empty_mapping_and_a_name_yaml_reads_as_a_number_take_overrides(tmp_path):
    config = tmp_path / "empty.yaml"
    config.write_text(
        "name: empty\nscene:\n  body: {mass: 1.0, inertia: [1.0, 1.0, 2.0]}\n"
        "  initial: {angular_velocity: {body: [0.25, 0.0, 6.0]}}\n  nodes: {2: [1.0, 0.0, 0.0]}\n"
        "  duration: 0.5\noutput:\nrun: {scheme: rk4, dt: 0.01}\n"
    )
    study = load_study(config, ["output.interval=0.05", "scene.nodes.2=[0, 0, 2]"])
    assert study.output_interval == 0.05 and study.base["scene"]["nodes"] == {2: [0, 0, 2]}


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (
            ["--set", "sweep.dt.count=0"],
            "{config}: --set sweep.dt.count: expected a whole number >= 1, got 0",
        ),
        (
            ["--set", "sweep.dt.count3"],
            "{config}: --set sweep.dt.count3: no '=' in "
            "'sweep.dt.count3'; write it as KEY=VALUE, for example "
            "--set sweep.dt.count=3",
        ),
        (
            ["--set", "sweep.dt=[0.01, 0.005"],
            "{config}: --set sweep.dt: line 1: malformed YAML: expected ',' or ']', but got '<stream end>'",
        ),
        (
            ["--set", "run.dt.x=1"],
            "{config}: --set run.dt.x: run.dt holds 0.01, not a mapping or "
            "list; set run.dt itself, or a key under a mapping",
        ),
        (
            ["--set", "scene.body.inertia.3=1"],
            "{config}: --set scene.body.inertia.3: '3' is not an "
            "entry of the list of 3 at scene.body.inertia; use "
            "an index 0..2",
        ),
        (
            ["--set", "scene.body.inertia.1=-1"],
            "{config}: --set scene.body.inertia[1]: must be > 0 kg m^2, got -1",
        ),
        (
            ["--set", "run.scheme=hhtt"],
            "{config}: --set run.scheme: unknown scheme 'hhtt' (did you mean 'hht'?); valid schemes: ",
        ),
        # a key no study knows is refused with the one that was meant, made or not by the file
        (
            ["--set", "scene.duraton=1"],
            "{config}: --set scene.duraton: unknown key (did you mean "
            "'duration'?); valid keys here: body, assembly, initial, "
            "nodes, pivot, loads, duration",
        ),
        (
            ["--set", "scene.laods.moment_body=[0, 0, 1]"],
            "{config}: --set scene.laods: unknown key (did you mean 'loads'?); valid keys here",
        ),
        (
            ["--set", "run.options.alpah=-0.1"],
            "{config}: --set run.options.alpah: alpah is an option of "
            "none of the study's schemes (hht, rk4) (did you mean "
            "'alpha'?); remove it (or --set 'run.options={{}}'); `rbstudy schemes` lists "
            "each scheme's options",
        ),
        (
            ["--set", "sweep.dt.cout=3"],
            "{config} (with --set sweep.dt.cout=3): sweep.dt: expected a list of values, ",
        ),
        # an error elsewhere that an override may have caused names the file with the overrides
        (
            ["--set", "output.interval=0.003"],
            "{config} (with --set output.interval=0.003): sweep "
            "(scheme[0] = 'rk4', dt[0] = 0.005): run.dt: dt = 0.005 s "
            "does not divide the output interval 0.003 s",
        ),
    ],
)
def test_a_bad_override_is_one_line_and_writes_nothing(tmp_path, capsys, argv, line):
    config = write_study(tmp_path, sweep=SWEEP)
    for verb in ("validate", "sweep"):
        assert main([verb, str(config), "--out", str(tmp_path / "out"), *argv]) == 1
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and error.startswith("rbstudy: error: " + line.format(config=config)), (
            error
        )
    assert not (tmp_path / "out").exists()
    if "cout" in argv[1]:
        assert error.rstrip().endswith("(did you mean 'count'?)")


def test_several_files_each_take_the_overrides_or_refuse_them(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    damped = write_study(tmp_path / "a", name="damped", sweep=SWEEP)
    plain = write_study(tmp_path / "b", name="plain", sweep={"dt": [0.01, 0.005]})
    assert main(["validate", str(damped), str(plain), "--set", "sweep.dt=[0.01]"]) == 0
    said = _said(capsys)
    assert "damped: 2 cases (scheme 2 x dt 1)" in said and "plain: 1 case" in said
    # alpha means something to one of them only: the other is refused, and nothing is run
    argv = [
        "sweep",
        str(damped),
        str(plain),
        "--out",
        str(tmp_path / "out"),
        "--set",
        "run.options.alpha=-0.1",
    ]
    assert main(argv) == 1
    assert capsys.readouterr().err == (
        f"rbstudy: error: {plain}: --set run.options.alpha: alpha is an option of none of the "
        "study's schemes (rk4); remove it (or --set 'run.options={}'), or sweep a scheme that "
        "takes it (hht)\n"
    )
    assert not (tmp_path / "out").exists()


def _runs(capsys):
    """(batches run, reused) of the sweep whose output ``capsys`` holds, or "up to date"."""
    said = _said(capsys)
    if "is up to date" in said:
        return "up to date"
    run, reused = re.search(r"(\d+) batch(?:es)? run, (\d+) reused", said).groups()
    return int(run), int(reused)


@pytest.mark.slow
def test_overrides_are_states_of_one_study_for_the_resume_rules(tmp_path, capsys):
    """The same overrides find the archive up to date; others are another state of the same
    study (the folder is not refused as another config's): the batches they change are run,
    the others reused where parts are kept, and the file alone is its first state again."""
    config = write_study(tmp_path, name="top", sweep=SWEEP)
    out, folder = tmp_path / "out", tmp_path / "out" / "top"
    damped = ["--set", "run.options.alpha=-0.1"]
    _sweep(config, out, "--keep-parts")
    assert _runs(capsys) == (4, 0)
    owner = (folder / OWNER).read_text()
    first = open_results(folder / "top.nc")
    _sweep(config, out, "--keep-parts", *damped)
    assert _runs(capsys) == (2, 2)  # hht's two batches: alpha is not rk4's option
    assert (folder / OWNER).read_text() == owner  # the file owns the folder, whatever --set
    _sweep(config, out, "--keep-parts", *damped)
    assert _runs(capsys) == "up to date"
    changed = open_results(folder / "top.nc")
    hht, rk4 = {"scheme": "hht"}, {"scheme": "rk4"}
    assert not changed.orientation_error.sel(hht).equals(first.orientation_error.sel(hht))
    assert changed.orientation_error.sel(rk4).equals(first.orientation_error.sel(rk4))
    _sweep(config, out, "--keep-parts", "--set", "title=Renamed", *damped)
    assert _runs(capsys) == "up to date"  # a title is no new numbers: redescribed in place
    assert open_results(folder / "top.nc").attrs["title"] == "Renamed"
    # back to the file alone: the parts of its hht batches were replaced, rk4's are kept
    _sweep(config, out, "--keep-parts")
    assert _runs(capsys) == (2, 2)
    again = open_results(folder / "top.nc")
    assert again.attrs["overrides"] == "" and again.attrs["config"] == config.read_text()
    assert again.orientation_error.equals(first.orientation_error)
    # without --keep-parts the parts go once the archive is written: a change recomputes all
    _sweep(config, out, *damped)
    assert _runs(capsys) == (2, 2)
    _sweep(config, out)
    assert _runs(capsys) == (4, 0)
    # a copy of the file elsewhere, with overrides, is the same study; another file is not
    moved = tmp_path / "elsewhere.yaml"
    moved.write_text(config.read_text())
    _sweep(moved, out, *damped)
    assert _runs(capsys) == (4, 0)
    (tmp_path / "other").mkdir()
    other = write_study(tmp_path / "other", name="top", sweep={"scheme": ["hht"], "dt": [0.01]})
    assert main(["sweep", str(other), "--out", str(out), "--quiet", *damped]) == 1
    assert "holds the study of another config of this name" in capsys.readouterr().err
