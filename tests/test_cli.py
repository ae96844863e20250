"""The command line: sweep writes a CF dataset; bad configs give one line, exit 2, no file."""

import re

import pytest
import yaml
from helpers import CONFIGS, abaqus_mapping, listed_schemes, write_study

from rbstudy.archive.load import open_results
from rbstudy.cli import build_parser, main


@pytest.mark.slow
def test_sweep_writes_the_study_layout_and_prints_the_summary(tmp_path, capsys):
    config = write_study(
        tmp_path, name="small", sweep={"scheme": ["rk4", "hht"], "dt": [0.01, 0.005, 0.0025]}
    )
    assert main(["sweep", str(config), "--out", str(tmp_path / "out")]) == 0
    folder = tmp_path / "out" / "small"
    # the archive holds everything: parts/ goes once it is written
    assert sorted(p.name for p in folder.iterdir()) == [
        ".lock",
        ".lock.pid",
        ".rbstudy-study",
        "small.nc",
        "study.yaml",
    ]
    assert (
        main(["sweep", str(config), "--out", str(tmp_path / "kept"), "--keep-parts", "--quiet", "--wide"])
        == 0
    )  # the inaccurate cases: a wide column
    parts = tmp_path / "kept" / "small" / "parts"
    # one per scheme and dt, each with its digest, no temporaries
    assert sorted(p.suffix for p in parts.iterdir()) == [".npz"] * 6 + [".sha256"] * 6
    resolved = yaml.safe_load((folder / "study.yaml").read_text())
    assert resolved["sweep"]["dt"] == {"dt": [0.0025, 0.005, 0.01]} and resolved["cases"] == 6
    out = capsys.readouterr().out
    assert "small: 6 cases (scheme 2 x dt 3) in 6 batches" in out and "6 batches run" in out
    rows = {
        line.split()[0]: line.split() for line in out.splitlines() if line.split()[:1] in (["rk4"], ["hht"])
    }  # the wide table's, printed last
    assert rows["rk4"][1:3] == ["4", "4.00"] and rows["hht"][1:3] == ["2", "2.00"]  # nominal, fit
    assert rows["hht"].count("0/3") == 2  # none of the three cases inaccurate, none failed


def test_a_one_case_study_names_its_scheme_and_dt(tmp_path, capsys):
    config = write_study(tmp_path, name="one", run={"scheme": "splitting", "dt": 0.005})
    assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    ds = open_results(tmp_path / "out" / "one" / "one.nc")
    assert str(ds.scheme.values) == "splitting" and float(ds.dt) == 0.005
    assert ds.omega_body.dims == ("time", "axis") and int(ds.n_steps) == 100
    row = next(
        line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("splitting ")
    )  # the table row, not the verdict
    assert row[2] == "n/a" and row[-3:] == ["0/1", "|L|,", "L"]  # no dt axis: no order; L kept


def test_validate_reports_cases_batches_and_memory(capsys):
    assert main(["validate", "configs/abaqus_top.yaml"]) == 0
    out = capsys.readouterr().out
    assert max(map(len, out.splitlines())) <= 100  # wrapped after its clauses
    out = " ".join(out.split())
    assert "216 cases (scheme 9 x dt 6 x inertia_ratio 4) in 54 batches" in out
    assert "archive ~" in out and "peak memory" in out  # the sizes: test_pipeline
    assert "4.5e+05 body-steps" in out  # 216 cases of 2 s at dt 0.01 .. 0.0003125


@pytest.mark.slow  # 1.8 s at a load of 5 on 2 cores: three studies of ~1,900 cases validated
def test_validate_advises_zarr_only_past_its_threshold(tmp_path, capsys, monkeypatch):
    """A netCDF study whose forecast archive passes `ZARR_ADVISED_BYTES` by one case gets one
    line naming the fix; one case fewer, the same study stored as zarr and the default get none."""
    from rbstudy.pipeline import estimate
    from rbstudy.pipeline.config import load_study

    monkeypatch.setattr(estimate, "_free_bytes", lambda folder: 2**50)  # their parts and archive

    def study(name, cases, **output):  # 8,001 samples a case: ~1,900 cases past 4 GiB
        return write_study(
            tmp_path,
            name=name,
            scene={**abaqus_mapping(), "duration": 4.0},
            output={"interval": 0.0005, **output},
            run={"scheme": "leapfrog", "dt": 0.0005},
            sweep={"tilt": {"linspace": [1, 60, cases]}},
        )

    past = estimate.ZARR_ADVISED_BYTES // load_study(study("probe", 2), []).bytes_per_case() + 1
    files = [study("past", past), study("within", past - 1), study("zarr", past, format="zarr")]
    assert main(["validate", *map(str, files), "configs/abaqus_top.yaml", "--max-memory", "1e7"]) == 0
    out = capsys.readouterr().out
    assert max(map(len, out.splitlines())) <= 100
    text = " ".join(out.split())
    assert text.count("advice:") == 1, text
    assert (
        f"{files[0]}: advice: over 4 GiB of values: output.format: zarr in the config, or sweep "
        "--format zarr" in text
    )


def test_the_default_step_limit_is_the_estimates(capsys):
    from rbstudy.pipeline import estimate

    assert build_parser().parse_args(["validate", "x"]).max_body_steps == estimate.MAX_BODY_STEPS


def test_a_runaway_study_is_refused_with_its_estimate_and_leaves_nothing(tmp_path, capsys):
    """dt = 1e-9 over 1000 s: 1e12 steps, which validate used to call ok and sweep to start."""
    config = write_study(
        tmp_path,
        name="runaway",
        run={"scheme": "rk4", "dt": 1e-9},
        output={"interval": 1.0},
        scene={**abaqus_mapping(), "duration": 1000.0},
    )
    for verb in ("validate", "sweep"):
        assert main([verb, str(config), "--out", str(tmp_path / "out")]) == 1
        error = capsys.readouterr().err.strip()
        assert re.fullmatch(
            rf"rbstudy: error: {re.escape(str(config))}: run\.dt: needs 1e\+12 body-steps, "
            r"kernels ~[\d,]+ h on \d+ cores? \(limit 1e\+11, --max-body-steps\); use a larger dt, a "
            r"shorter duration or fewer cases, or raise --max-body-steps",
            error,
        ), error
    assert not (tmp_path / "out").exists()
    assert main(["validate", str(config), "--max-body-steps", "2e12"]) == 0


def test_a_study_past_the_memory_or_the_free_disk_is_refused(tmp_path, capsys, monkeypatch):
    from rbstudy.pipeline import estimate

    config = write_study(tmp_path, sweep={"dt": {"halving": 0.01, "count": 4}})
    assert main(["validate", str(config), "--max-memory", "100"]) == 1
    error = capsys.readouterr().err
    assert "MiB of memory at once (limit 100 MiB, --max-memory)" in error
    monkeypatch.setattr(estimate, "_free_bytes", lambda folder: 1000)
    assert main(["sweep", str(config), "--out", str(tmp_path / "out")]) == 1
    error = capsys.readouterr().err
    assert "MiB on disk for its parts and archive; 0.0 MiB are free under" in error
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "text, message",
    [
        (
            "name: x\nscene: {body: {inertia: [1, 1, 1]}}\nrun: {scheme: leapfrg, dt: 0.1}\n",
            "bad.yaml: run.scheme: unknown scheme 'leapfrg' (did you mean 'leapfrog'?); valid schemes: buss, "
            "dop853, euler",
        ),
        (
            "name: x\nscene: {body: {inertia: [1, 1, 1]}}\nrun: {scheme: rk4, dt: 0.03}\n"
            "output: {interval: 0.1}\n",
            "bad.yaml: run.dt: dt = 0.03 s does not divide the output",
        ),
        (
            "name: x\nscene: {body: {inertia: [1, 1, 3]}}\nrun: {scheme: rk4, dt: 0.1}\n",
            "bad.yaml: scene.body.inertia: [1.0, 1.0, 3.0] violates the triangle inequality",
        ),
        (
            "name: x\nscene: {body: {inertia: [1, 1, 1]}}\nrun: {scheme: rk4, dt: 0.1}\nsweeps: 1\n",
            "bad.yaml: sweeps: unknown key",
        ),
        (
            "name: x\nscene: {body: {inertia: [1, 1, 1]}}\nrun: {scheme: rk4, dt: 0.1}\n"
            "output: {interval: 0.1}\nsweep: {dt: [0.1, 0.03]}\n",
            "bad.yaml: sweep (dt[0] = 0.03): run.dt: dt = 0.03 s does not divide",
        ),
        ("name: x\nscene: [1, 2\n", "bad.yaml: line 3: malformed YAML"),
    ],
)
def test_bad_configs_fail_in_one_line_with_nothing_written(tmp_path, capsys, text, message):
    config = tmp_path / "bad.yaml"
    config.write_text(text)
    out = tmp_path / "results"
    for verb in (["validate", str(config)], ["sweep", str(config), "--out", str(out)]):
        assert main(verb) == 1
        error = capsys.readouterr().err.strip()
        assert "\n" not in error and message.replace("bad.yaml", str(config)) in error, error
    assert not out.exists()


def test_unwritable_output_folder_is_one_line(tmp_path, capsys):
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    assert main(["sweep", "configs/abaqus_top.yaml", "--out", str(blocked)]) == 1
    error = capsys.readouterr().err.strip()
    assert error == (
        f"rbstudy: error: --out {blocked}: is a file, not a folder; choose another folder with --out"
    )  # more cases: test_file_system.py


def test_schemes_lists_the_registry(capsys):
    assert main(["schemes"]) == 0
    listing = capsys.readouterr().out
    for name in ("euler", "leapfrog", "rk4", "midpoint", "hht", "splitting", "no_squish", "rkmk4", "dop853"):
        assert f"\n{name} " in listing


def test_version_and_a_quick_bench(capsys):
    from importlib import metadata

    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"rbstudy {metadata.version('rbstudy')}"
    assert main(["bench", "euler", "--body-steps", "2000", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "~2e+03 body-steps per figure" in out
    row = next(line.split() for line in out.splitlines() if line.startswith("euler"))
    assert len(row) == 8 and all(float(rate) > 0 for rate in row[2:])


def test_bench_repeat_takes_the_best_of_its_runs(capsys, monkeypatch):
    """`bench --repeat N`: each figure is the fastest of N rounds of the table (a busy machine
    only slows a run), said in the table's first line; N outside 1..100 is one error line."""
    from rbstudy.pipeline import bench

    rates = iter([1e6] * 6 + [3e6] * 6 + [2e6] * 6)  # three rounds of six figures, the second fastest
    monkeypatch.setattr(bench, "_rate", lambda *args: (next(rates), None))
    assert main(["bench", "euler", "--body-steps", "2000", "--repeat", "3", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "per figure, the best of 3 rounds," in out and max(map(len, out.splitlines())) <= 100
    row = next(line.split() for line in out.splitlines() if line.startswith("euler"))
    assert [float(rate) for rate in row[2:]] == [3e6] * 6
    for bad in ("0", "101"):
        assert main(["bench", "euler", "--repeat", bad, "--quiet"]) == 1
        assert capsys.readouterr().err == f"rbstudy: error: --repeat: need 1 to 100, got {bad}\n"


def test_schemes_name_the_invariants_they_keep(capsys):
    assert main(["schemes"]) == 0
    listing = capsys.readouterr().out
    rows = listed_schemes(listing)
    assert " energy, L " in rows["midpoint"] and " L " in rows["splitting"]
    assert max(map(len, listing.splitlines())) <= 100  # the summaries wrap under their column
    assert "momentum" not in rows["midpoint"]


# What each engine's step solves (its adapter's docstring, and the engine's own docs):
# velocities then positions (semi-implicit), one linear solve in the new velocity (linearly
# implicit), Newton iterations (implicit).
ENGINE_KINDS = {
    "mujoco_euler": "semi-implicit",
    "mujoco_implicit": "linearly implicit",
    "mujoco_implicitfast": "linearly implicit",
    "mujoco_rk4": "explicit",
    "bullet_multibody": "semi-implicit",
    "bullet_rigidbody": "linearly implicit",
    "drake_discrete": "semi-implicit",
    "drake_implicit_euler": "implicit",
    "drake_rk2": "explicit",
    "exudyn_genalpha": "implicit",
    "exudyn_rk44": "explicit",
}


def test_schemes_say_what_each_step_solves(capsys):
    """The kind column, read under its header: no engine that solves for its new velocity is
    called explicit (issue 41)."""
    assert main(["schemes"]) == 0
    listing = capsys.readouterr().out
    header = listing.splitlines()[0]
    start, end = header.index("kind"), header.index("keeps")
    kinds = {name: row[start:end].strip() for name, row in listed_schemes(listing).items()}
    assert {kinds[name] for name in ("hht", "midpoint")} == {"implicit"} and kinds["dop853"] == "adaptive"
    assert {kinds[name] for name in ("euler", "rk4", "splitting")} == {"explicit"}
    installed = {name: kind for name, kind in ENGINE_KINDS.items() if kinds.get(name) != "unavailable"}
    assert {name: kinds[name] for name in installed} == installed


def test_limits_name_the_option_given(tmp_path, capsys):
    config = write_study(tmp_path)
    for option in ("--max-memory", "--max-body-steps"):
        assert main(["validate", str(config), option, "-5"]) == 1
        assert capsys.readouterr().err.strip() == f"rbstudy: error: {option} takes a number above 0, got -5"


def test_validate_notes_an_option_that_only_some_schemes_take(tmp_path, capsys):
    config = write_study(
        tmp_path,
        run={"scheme": "hht", "options": {"alpha": 0.0}, "dt": 0.01},
        sweep={"scheme": ["hht", "rk4"]},
    )
    assert main(["validate", str(config)]) == 0
    said = " ".join(capsys.readouterr().out.split())  # wrapped within 100 columns
    assert f"{config}: note: run.options.alpha applies to hht only; the other schemes run without it" in said


def test_the_magnitude_drift_has_its_name_and_the_old_one_still_works(tmp_path):
    """max_momentum_error was the drift of |L|, next to momentum_error, the vector's: renamed
    max_momentum_magnitude_error; the old name stays an alias for one release."""
    config = write_study(
        tmp_path, name="alias", output={"interval": 0.01, "variables": ["quaternion", "max_momentum_error"]}
    )
    assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    ds = open_results(tmp_path / "out" / "alias" / "alias.nc")
    assert float(ds.max_momentum_error) == float(ds.max_momentum_magnitude_error)
    assert "magnitude |L|" in ds.max_momentum_magnitude_error.attrs["description"]
    alias = ds.max_momentum_error.attrs
    assert alias["long_name"] == "deprecated alias of max_momentum_magnitude_error"
    # the archive and config.md name one release it goes in, a later one than this
    removed = re.fullmatch(r"removed in rbstudy (\d+)\.(\d+): .*", alias["description"])
    assert tuple(map(int, removed.groups())) > tuple(map(int, ds.attrs["source"].split()[1].split(".")[:2]))
    config_md = (CONFIGS.parent / "docs" / "config.md").read_text()
    assert config_md.count(f"removed in {removed[1]}.{removed[2]}") == 2  # dataset, changes
    assert not re.search(r"removed in (rbstudy )?0\.[0-4]\b", config_md)


GOOD = (
    "name: x\nscene: {body: {inertia: [1, 1, 2]}, initial: {angular_velocity: {body: [0.1, 0, 1]}}}\n"
    "run: {scheme: rk4, dt: 0.1}\noutput: {interval: 0.1}\n"
)
# nine levels of nine aliases, under `title` (490 million values once expanded)
BOMB = "title:\n  a0: &a0 x\n" + "".join(
    f"  a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 9) + "]\n" for k in range(1, 10)
)


@pytest.mark.slow
@pytest.mark.parametrize(
    "content, message",
    [
        (
            GOOD.replace("name: x", "name: x\ntitle: caf\xe9").encode("latin-1"),
            "is not UTF-8 text (byte 0xe9 at offset 18); save the file as UTF-8",
        ),
        (GOOD.encode("utf-16"), "is not UTF-8 text"),
        (bytes(range(256)) * 4, "is not UTF-8 text"),
        (GOOD + "name: other\n", "line 5: malformed YAML: duplicate key 'name'"),
        (GOOD + "sweep: " + "{a: " * 5000 + "1" + "}" * 5000 + "\n", "nested"),
        (
            GOOD + "sweep:\n  spin: " + "[" * 40 + "1" + "]" * 40 + "\n",
            "sweep: nested 42 levels deep (at most 32)",
        ),
        (BOMB + GOOD, "title: its aliases expand to 490,329,066 values (at most 100,000 more than the"),
        (GOOD.replace("name: x", "name: x\ntitle: |\n  two\n  lines"), "title: expected one line of text"),
        (GOOD + "sweep: {tilt: [.inf]}\n", "sweep.tilt[0]: must be finite, got inf"),
        (GOOD + "sweep: {spin: [.inf]}\n", "sweep.spin[0]: must be finite, got inf"),
        (GOOD + "sweep: {spin: [0.0]}\n", "sweep (spin[0] = 0.0): spin must be > 0 rad/s"),
        (
            GOOD + "sweep: {dt: {halving: 0.01, count: 1100}}\n",
            "sweep.dt.count: 1,100 is too many; at most 60",
        ),
        (
            GOOD + "sweep: {inertia_ratio: {linspace: [0.1, 2.0, 1000000000000]}}\n",
            "sweep.inertia_ratio.linspace[2]: 1,000,000,000,000 is too many; at most 1,000,000",
        ),
        (
            GOOD.replace("name: x", "name: x\ntitle: &a [*a]"),
            "title: an alias refers to itself; write the values out",
        ),
        (
            GOOD.replace("dt: 0.1", "dt: 1.0e-320"),
            "run.dt: dt = 9.99989e-321 s is too small for the output interval 0.1 s",
        ),
        (GOOD + "sweep: {dt: {halving: 1.0e-320, count: 6}}\n", "is too small for the output"),
        (
            GOOD.replace("inertia: [1, 1, 2]}", "inertia: [1, 1, 2]}, duration: 1" + "0" * 5000),
            "holds a value that cannot be read",
        ),
        (
            GOOD.replace("{inertia: [1, 1, 2]}", "{mass: 1" + "0" * 400 + ", inertia: [1, 1, 2]}"),
            "scene.body.mass: must be finite",
        ),
        (
            GOOD.replace("inertia: [1, 1, 2]}", "inertia: [1, 1, 2]}, duration: 2001-12-14"),
            "scene.duration: expected a number, got '2001-12-14'",
        ),
        (
            GOOD.replace("dt: 0.1}", 'dt: 0.1, options: {"alpha\\nfoo": 0.0}}'),
            "alpha\\nfoo is an option of none",
        ),
        (
            GOOD.replace("name: x", "name: x\ntitle: [" + ", ".join(["7"] * 90000) + "]"),
            "title: expected one line of text, got [7, 7",
        ),
        (
            GOOD + "sweep: {spin: [1.0e308]}\n",
            "sweep (spin[0] = 1e+308): scene.initial."
            "angular_velocity.body: so large that the body's energy overflows a float",
        ),
    ],
)
def test_hostile_configs_fail_in_one_line_with_nothing_written(tmp_path, capsys, content, message):
    config = tmp_path / "bad.yaml"
    config.write_bytes(content if isinstance(content, bytes) else content.encode())
    out = tmp_path / "results"
    for verb in (["validate", str(config)], ["sweep", str(config), "--out", str(out)]):
        assert main(verb) == 1
        error = capsys.readouterr().err.strip()
        assert "\n" not in error and f"{config}: " in error and message in error, error
    assert not out.exists()


def test_a_bug_shows_its_traceback_once_with_where_to_report_it(capsys, monkeypatch):
    from rbstudy import cli

    def broken(args):
        raise ZeroDivisionError("a bug")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    parser._subparsers._group_actions[0].choices["schemes"].set_defaults(run=broken)
    assert main(["schemes"]) == cli.EXIT_BUG == 70
    error = capsys.readouterr().err
    assert "Traceback" in error and "ZeroDivisionError: a bug" in error
    assert error.strip().endswith("please report it with the command, the config and the lines above")


def test_bad_usage_is_exit_two(capsys):
    with pytest.raises(SystemExit) as done:
        main(["sweep"])
    assert done.value.code == 2


@pytest.mark.slow
def test_a_closed_output_ends_the_command_quietly():
    """`rbstudy ... | head -1`: the reader is gone; no traceback, exit 141 (not a success:
    what was not yet done is not done)."""
    import subprocess
    import sys

    process = subprocess.Popen(
        [sys.executable, "-m", "rbstudy", "schemes"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    process.stdout.close()  # the reader leaves before anything is written
    assert process.wait(timeout=120) == 141
    assert process.stderr.read() == b""


def test_yaml_merge_keys_still_merge(tmp_path, capsys):
    config = tmp_path / "merge.yaml"
    config.write_text(GOOD.replace("run: {scheme: rk4, dt: 0.1}", "run: {<<: {scheme: rk4}, dt: 0.1}"))
    assert main(["validate", str(config)]) == 0
    assert "ok: x: 1 case (one case)" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "meant"),
    [
        (["swep", "x.yaml"], "(did you mean 'sweep'?)"),
        (["sweep", "--wokers", "2", "x.yaml"], "(did you mean '--workers'?)"),
        (["validate", "x.yaml", "--max-memroy", "100"], "(did you mean '--max-memory'?)"),
    ],
)
def test_a_slip_of_a_verb_or_an_option_is_offered_what_was_meant(argv, meant, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(meant)


def test_a_slip_of_a_scheme_or_a_key_is_offered_what_was_meant(tmp_path, capsys):
    scheme = write_study(tmp_path, name="scheme", run={"scheme": "hhtt", "dt": 0.01})
    key = write_study(tmp_path, name="key")
    key.write_text(key.read_text().replace("duration:", "duraton:"))
    far = write_study(tmp_path, name="far", run={"scheme": "xyz", "dt": 0.01})
    assert main(["validate", str(scheme), str(key), str(far)]) == 1
    errors = capsys.readouterr().err.splitlines()
    assert "run.scheme: unknown scheme 'hhtt' (did you mean 'hht'?); valid schemes:" in errors[0]
    assert "scene.duraton: unknown key (did you mean 'duration'?); valid keys here:" in errors[1]
    assert "unknown scheme 'xyz'; valid schemes:" in errors[2]  # nothing near: no guess
