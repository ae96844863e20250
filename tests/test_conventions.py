"""One command-line convention (issue 30): every verb that reads archives takes many, every
count takes ``1e6``, list options take a comma list or the option again and never a
positional, schemes are named the same way on bench and conformance, ``-o``/``-q`` on every
verb, and a slip is offered what was meant."""

import argparse

import pytest
from helpers import abaqus_mapping, write_study

from rbstudy.cli import build_parser, main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

# what each verb needs to parse at all
POSITIONALS = {
    "sweep": ["x.yaml"],
    "validate": ["x.yaml"],
    "plot": ["x.nc"],
    "report": ["x.nc"],
    "summary": ["x.nc"],
    "verify": ["x.nc"],
}


def _verbs():
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def _archive(folder, name):
    """A real archive of two schemes at two steps over 0.2 s, study ``name``."""
    config = write_study(
        folder,
        name=name,
        scene={**abaqus_mapping(), "duration": 0.2},
        output={"interval": 0.02},
        sweep={"scheme": ["euler", "rk4"], "dt": [0.02, 0.01]},
    )
    return run_study(load_study(config), folder / "out", quiet=True).path


@pytest.fixture(scope="module")
def archives(tmp_path_factory):
    root = tmp_path_factory.mktemp("archives")
    return [_archive(root, name) for name in ("first", "second")]


def test_every_verb_takes_q_and_every_verb_with_an_output_folder_o():
    verbs = _verbs()
    assert set(verbs) == {*POSITIONALS, "schemes", "bench", "conformance"}
    for verb, parser in verbs.items():
        quiet = parser._option_string_actions["-q"]
        assert quiet is parser._option_string_actions["--quiet"] and quiet.help, verb
        assert build_parser().parse_args([verb, *POSITIONALS.get(verb, []), "-q"]).quiet
        if "--out" in parser._option_string_actions:
            assert parser._option_string_actions["-o"].dest == "out", verb
    writers = {verb for verb, parser in verbs.items() if "-o" in parser._option_string_actions}
    assert writers == {"sweep", "validate", "plot", "report", "conformance"}


@pytest.mark.parametrize(
    ("argv", "dest", "value"),
    [
        (["bench", "--body-steps", "1e6"], "body_steps", 1_000_000),
        (["sweep", "x.yaml", "--workers", "2e0"], "workers", 2),
        (["conformance", "--steps", "5e0"], "steps", 5),
        (["validate", "x.yaml", "--max-body-steps", "1e6"], "max_body_steps", 1e6),
    ],
)
def test_every_count_takes_an_exponent(argv, dest, value):
    assert getattr(build_parser().parse_args(argv), dest) == value


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "--body-steps", "1.5"],
        ["sweep", "x.yaml", "--workers", "2.5"],
        ["conformance", "--steps", "four"],
    ],
)
def test_a_count_that_is_no_whole_number_is_bad_usage(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    assert "expected a whole number, got" in capsys.readouterr().err


def test_bench_takes_1e3_body_steps_and_its_schemes_either_way(capsys):
    rows = []
    for schemes in (
        ["euler", "rk4"],
        ["--schemes", "euler,rk4"],
        ["euler", "--schemes", "rk4"],
        ["--schemes", "euler", "--schemes", "rk4"],
    ):
        assert main(["bench", *schemes, "--body-steps", "1e3", "-q"]) == 0
        out = capsys.readouterr().out
        assert "~1e+03 body-steps per figure" in out
        assert max(map(len, out.splitlines())) <= 100
        rows.append(
            [line.split()[0] for line in out.splitlines() if line.split()[-1][0].isdigit()]
        )  # a row ends with a rate
    assert rows == [["euler", "rk4"]] * 4


@pytest.mark.parametrize("given", [["--schemes", "euler,rk4"], ["--schemes", "euler", "--schemes", "rk4"]])
def test_conformance_takes_schemes_and_cases_as_bench_does(given):
    args = build_parser().parse_args(["conformance", *given, "--cases", "t_handle,abaqus_top"])
    assert args.schemes == ["euler", "rk4"] and args.cases == ["t_handle", "abaqus_top"]


def test_a_list_option_never_takes_a_positional():
    """`plot --format svg X.nc` took X.nc for a second format (nargs="+")."""
    parser = build_parser()
    assert parser.parse_args(["plot", "--format", "svg", "X.nc"]).files == ["X.nc"]
    both = parser.parse_args(["plot", "--format", "png", "--format", "svg", "X.nc", "Y.nc"])
    assert both.format == ["png", "svg"] and both.files == ["X.nc", "Y.nc"]
    assert parser.parse_args(["plot", "X.nc", "--format", "png,svg"]).format == ["png", "svg"]
    assert parser.parse_args(["bench", "--schemes", "rk4", "euler"]).scheme_names == ["euler"]


@pytest.mark.slow
def test_plot_format_svg_then_the_file_draws_that_file(archives, tmp_path, capsys):
    assert main(["plot", "--format", "svg", str(archives[0]), "-o", str(tmp_path / "f")]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert line.startswith(f"{archives[0]}: ") and "figures (SVG)" in line
    assert list((tmp_path / "f").glob("first_*.svg")) and not list(tmp_path.rglob("*.png"))
    # a list given twice over draws each format once
    assert (
        main(
            [
                "plot",
                "--format",
                "png,svg",
                "--format",
                "png",
                str(archives[0]),
                "-o",
                str(tmp_path / "g"),
                "-q",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "figures (PNG and SVG)" in out and "not drawn" not in out  # -q: no notes
    assert main(["plot", "--format", "svg", str(tmp_path / "absent.nc")]) == 1  # read, not a format
    assert f"{tmp_path / 'absent.nc'}: no such file" in capsys.readouterr().err


@pytest.mark.slow
def test_report_writes_a_report_of_each_archive(archives, tmp_path, capsys):
    assert main(["report", *map(str, archives), "-q"]) == 0  # beside each archive
    out = capsys.readouterr().out.splitlines()
    assert out == [f"{path}: report in {path.parent / 'report' / 'report.html'}" for path in archives]
    assert main(["report", *map(str, archives), "-o", str(tmp_path / "reports"), "-q"]) == 0
    for study in ("first", "second"):  # a folder per study, each with its own figures
        folder = tmp_path / "reports" / study
        assert (folder / "report.html").is_file() and list(folder.glob(f"figures/{study}_*"))
        assert not list(folder.glob("figures/first_*" if study == "second" else "figures/second_*"))


def test_report_refuses_two_archives_of_one_study_and_writes_nothing(archives, tmp_path, capsys):
    out = tmp_path / "reports"
    assert main(["report", str(archives[0]), str(archives[1]), str(archives[0]), "-o", str(out)]) == 1
    error = capsys.readouterr().err.strip()
    assert error == (
        f"rbstudy: error: {archives[0]}: another file of this command is also "
        f"study 'first': their reports would overwrite each other in {out}; "
        "report them one at a time, each with its own -o"
    )
    assert not out.exists()
    copy = archives[0].parent / "copy.nc"
    copy.write_bytes(archives[0].read_bytes())
    try:  # the same folder: both reports would go to its report/
        assert main(["report", str(archives[1]), str(copy), str(archives[0])]) == 1
    finally:
        copy.unlink()
    assert capsys.readouterr().err.strip() == (
        f"rbstudy: error: {copy}: another file of this command lies in the same folder: their "
        f"reports would both go to {archives[0].parent / 'report'}; give -o DIR (a folder per "
        "study inside it)"
    )


def test_quiet_leaves_out_what_each_verb_says_it_does(archives, tmp_path, capsys):
    assert main(["schemes", "-q"]) == 0  # the names alone, for scripts
    names = capsys.readouterr().out.split()
    assert "rk4" in names and "hht" in names and all(" " not in name for name in names)
    assert main(["verify", *map(str, archives), "-q"]) == 0
    assert capsys.readouterr().out == ""  # intact: nothing to say
    assert main(["verify", str(archives[0]), str(tmp_path / "absent.nc"), "-q"]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and "absent.nc" in captured.err
    assert main(["summary", str(archives[0]), "-q"]) == 0
    table = capsys.readouterr().out
    assert table.startswith("scheme ") and "order" in table  # no findings above it
    assert main(["summary", str(archives[0])]) == 0
    assert not capsys.readouterr().out.startswith("scheme ")
    config = write_study(tmp_path, name="fine")
    assert main(["validate", str(config), "-q"]) == 0
    assert capsys.readouterr().out == ""


def test_a_config_count_may_be_written_with_an_exponent(tmp_path, capsys):
    """YAML reads `count: 1e3` as a float: a whole one is a count; any other is refused."""
    config = write_study(tmp_path, name="counted", sweep={"dt": {"halving": 0.01, "count": 3}})
    text = config.read_text()
    assert "count: 3\n" in text
    config.write_text(text.replace("count: 3\n", "count: 3e0\n"))
    assert main(["validate", str(config)]) == 0
    assert "3 cases (dt 3)" in " ".join(capsys.readouterr().out.split())  # wrapped
    config.write_text(text.replace("count: 3\n", "count: 2.5\n"))
    assert main(["validate", str(config)]) == 1
    assert capsys.readouterr().err.strip() == (
        f"rbstudy: error: {config}: sweep.dt.count: expected a whole number >= 1, got 2.5"
    )
    config.write_text(text.replace("count: 3\n", "count: 1e3\n"))
    assert main(["validate", str(config)]) == 1
    assert capsys.readouterr().err.strip() == (
        f"rbstudy: error: {config}: sweep.dt.count: 1000 is too many; at most 60"
    )


@pytest.mark.parametrize(
    ("argv", "usage", "meant"),
    [
        (["sweep", "x.yaml", "--wokers", "2"], "usage: rbstudy sweep ", "'--workers'"),
        (["sweep", "--wokers=2", "x.yaml"], "usage: rbstudy sweep ", "'--workers'"),
        (["bench", "--body-step", "10", "--schemse", "rk4"], "usage: rbstudy bench ", "'--schemes'"),
        (["plot", "--format", "svgg", "x.nc"], "usage: rbstudy plot ", "'svg'"),
        (["swep", "x.yaml"], "usage: rbstudy [", "'sweep'"),
    ],
)
def test_a_slip_on_the_command_line_is_told_with_its_verb_and_what_was_meant(argv, usage, meant, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    error = capsys.readouterr().err
    assert error.startswith(usage) and error.strip().endswith(f"(did you mean {meant}?)"), error


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "hhtt", "--body-steps", "10"],
        ["bench", "--schemes", "hhtt", "--body-steps", "10"],
        ["conformance", "--schemes", "hhtt"],
    ],
)
def test_a_slip_of_a_scheme_name_is_offered_what_was_meant_on_every_verb(argv, tmp_path, capsys):
    assert main([*argv, *(["-o", str(tmp_path / "c")] if argv[0] == "conformance" else [])]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "unknown scheme 'hhtt' (did you mean 'hht'?)" in error
    assert not (tmp_path / "c").exists()
