"""No Python warning or traceback on a path a user causes: a bad local cluster option, Ctrl-C
of the whole process group of a sweep with workers, a library's message of several lines,
and a file that is no archive at all. Each says its one line, and only that."""

import os
import pathlib
import signal
import socket
import subprocess
import sys
import time

import pytest
import yaml
from helpers import CONFIGS, HOSTILE, HOSTILE_SHOWN, TERMINAL_CONTROLS, write_study
from test_cluster import _parts, _slow_study

from rbstudy import cli
from rbstudy.cli import main
from rbstudy.commands import schemes as scheme_verbs
from rbstudy.errors import one_line
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

INTERRUPTED = "rbstudy: interrupted; finished batches are kept: rerun the same command to resume"


def _rbstudy(*args, **popen):
    return subprocess.Popen(
        [sys.executable, "-m", "rbstudy", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        **popen,
    )


@pytest.mark.slow
def test_a_bad_local_cluster_option_is_one_line_and_no_warning(tmp_path):
    """The option failed in the worker as it started: the worker's semaphores were reported
    as leaked by Python's resource tracker (a warning of two lines, twice) after the error.
    Now the count is refused as the cluster file is read, before any worker (or forecast)."""
    config = write_study(tmp_path, name="small")
    cluster = tmp_path / "cluster.yaml"
    cluster.write_text(yaml.safe_dump({"kind": "local", "jobs": 1, "options": {"threads_per_worker": -1}}))
    process = _rbstudy(
        "sweep", str(config), "--cluster", str(cluster), "--out", str(tmp_path / "out"), "--quiet"
    )
    error = process.communicate(timeout=300)[1]
    assert process.returncode == 1
    said = "options.threads_per_worker: expected a whole number >= 1, got -1"
    assert error == f"rbstudy: error: {cluster}: {said}\n"


@pytest.mark.slow
def test_ctrl_c_of_the_process_group_ends_a_sweep_with_workers_in_one_line(tmp_path):
    """Ctrl-C at a terminal reaches the sweep's whole process group, its two workers too,
    which printed 4 tracebacks (63 lines). Now they ignore it and the sweep ends them: its
    one line, exit 130, and a rerun reuses the batches that had finished."""
    config = _slow_study(tmp_path)
    folder = tmp_path / "out" / "slow"
    process = _rbstudy(
        "sweep", str(config), "--workers", "2", "--out", str(folder.parent), "--quiet", start_new_session=True
    )
    try:
        deadline = time.monotonic() + 300
        while not ((folder / "parts").exists() and _parts(folder)) and process.poll() is None:
            assert time.monotonic() < deadline, "no batch finished in 300 s"
            time.sleep(0.01)
        os.killpg(process.pid, signal.SIGINT)  # the group: its id is the sweep's pid
        error = process.communicate(timeout=120)[1]
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert "Traceback" not in error and "Warning" not in error
    assert error.strip() == INTERRUPTED and process.returncode == 130
    kept = _parts(folder)
    assert 1 <= len(kept) < 8, f"Ctrl-C came too late to test resuming ({len(kept)} parts)"
    resumed = run_study(load_study(config), folder.parent, quiet=True)
    assert (resumed.reused, resumed.computed) == (len(kept), 8 - len(kept))


def test_a_library_message_of_several_lines_is_passed_on_whole_in_one_line():
    xarray_said = ValueError(
        "did not find a match in any of xarray's currently installed IO "
        "backends ['netcdf4']. Consider ... installing additional IO "
        "dependencies, see:\nhttps://docs.xarray.dev/en/stable/"
        "getting-started-guide/installing.html\n"
    )
    assert one_line(xarray_said).endswith(
        "dependencies, see: https://docs.xarray.dev/en/stable/getting-started-guide/installing.html"
    )
    assert one_line(KeyError()) == "KeyError"


def test_a_bug_s_traceback_shows_the_text_it_quotes_as_escapes(monkeypatch, capsys):
    """A bug's message may quote a file's text: its traceback is shown, a terminal's
    control characters in it escaped."""

    def bug(args):
        raise ValueError(f"a library read {HOSTILE}")

    monkeypatch.setattr(scheme_verbs, "list_schemes", bug)
    assert main(["schemes"]) == cli.EXIT_BUG
    error = capsys.readouterr().err
    assert f"ValueError: a library read {HOSTILE_SHOWN}\n" in error
    assert not TERMINAL_CONTROLS.search(error), repr(error)


def test_a_job_cluster_s_advice_is_shown_whole(tmp_path, capsys):
    """dask-jobqueue's message ends its first line with "for example:" and gives the
    example on the next: the line quoted the first alone ("...for example:; see ...")."""
    pytest.importorskip("dask_jobqueue")
    cluster = tmp_path / "slurm.yaml"
    cluster.write_text(yaml.safe_dump({"kind": "slurm", "jobs": 1, "options": {"queue": "x"}}))
    config = write_study(tmp_path, name="small")
    assert (
        main(["sweep", str(config), "--cluster", str(cluster), "--out", str(tmp_path / "out"), "--quiet"])
        == 1
    )
    error = capsys.readouterr().err
    assert error.count("\n") == 1
    assert (
        "for example: cluster = SLURMCluster(cores=8, memory='24GB'); see the keyword "
        "arguments of SLURMCluster"
    ) in error


@pytest.mark.parametrize(
    "make, said",
    [
        (
            lambda path: path.write_text("name: tiny\nrun: {scheme: rk4}\n"),
            "not an rbstudy archive: not a netCDF file (a text file)",
        ),
        (lambda path: path.write_bytes(b""), "not an rbstudy archive: not a netCDF file (an empty file)"),
        (lambda path: path.write_bytes(bytes(range(256))), "not an rbstudy archive: not a netCDF file;"),
        (lambda path: path.mkdir(), "not an rbstudy archive: a folder, not a file"),
    ],
)
def test_verify_calls_a_non_archive_a_non_archive(tmp_path, capsys, make, said):
    path = tmp_path / "config.yaml"
    make(path)
    assert main(["verify", str(path)]) == 1
    error = capsys.readouterr().err
    assert error.startswith(f"rbstudy: error: {path}: {said}")
    assert "damaged" not in error and error.count("\n") == 1


def _unreadable(path, monkeypatch):
    """A file its user may not read (root reads any: the system's refusal is played then)."""
    path.write_bytes(b"\x89HDF\r\n\x1a\n")
    path.chmod(0)
    if os.geteuid() == 0:
        opened = os.open

        def refused(name, *args, **kwargs):
            if os.path.abspath(name) == str(path):
                raise PermissionError(13, "Permission denied", str(path))
            return opened(name, *args, **kwargs)

        monkeypatch.setattr(os, "open", refused)
    return str(path)


# path given -> what the line says of it (after "rbstudy: error: <path>: ")
INPUT_PATHS = {
    ".": "not an rbstudy archive: a folder, not a file",
    "./": "not an rbstudy archive: a folder, not a file",
    "/": "not an rbstudy archive: a folder, not a file",
    "/dev/null": "not an rbstudy archive: a character device, not a file",
    "/dev/zero": "not an rbstudy archive: a character device, not a file",
    "zero.nc": "not an rbstudy archive: a character device, not a file",  # a link to /dev/zero
    "fifo.nc": "not an rbstudy archive: a FIFO (named pipe), not a file",
    "absent.nc": "no such file",
    "unreadable.nc": "cannot read it: Permission denied",
}


@pytest.mark.parametrize("verb", ["verify", "summary", "plot", "report"])
def test_a_path_that_is_no_readable_file_is_one_line(tmp_path, capsys, monkeypatch, verb):
    """Before: `verify .`, `./` and `/` ended in "PosixPath('.') has an empty name" (exit 70);
    a device or a FIFO was called "no such file", an unreadable file a traceback."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "zero.nc").symlink_to("/dev/zero")
    os.mkfifo(tmp_path / "fifo.nc")
    _unreadable(tmp_path / "unreadable.nc", monkeypatch)
    out = ["--out", str(tmp_path / "out")] if verb in ("plot", "report") else []
    for path, said in INPUT_PATHS.items():
        assert main([verb, path, *out]) == 1, path
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and "Traceback" not in error, error
        assert error.startswith(f"rbstudy: error: {path}: {said}"), error
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("verb", ["verify", "summary", "plot", "report"])
def test_an_empty_path_is_said_to_be_one(tmp_path, capsys, verb):
    """`verify ''` (an unset shell variable) said "rbstudy: error: no such file", naming no path."""
    out = ["--out", str(tmp_path / "out")] if verb in ("plot", "report") else []
    assert main([verb, "", *out]) == 1
    assert capsys.readouterr().err == (
        "rbstudy: error: '': an empty path names no file; "
        "give the <study>.nc (or <study>.zarr) written by rbstudy sweep\n"
    )


def test_a_path_with_a_nul_character_is_one_line(tmp_path, capsys):
    """A NUL in a path (a node table's, given with --set) raised ValueError from os.stat:
    exit 70."""
    config = tmp_path / "radioss_body.yaml"
    config.write_text((CONFIGS / "radioss_body.yaml").read_text())
    assert main(["validate", str(config), "--set", 'scene.assembly.nodes="a\\0b.csv"']) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "cannot read the node table" in error, error
    assert main(["verify", str(tmp_path / "a\0b.nc")]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "no file's name holds a NUL character" in error, error


def test_an_error_naming_a_path_with_a_newline_is_one_line(tmp_path, capsys):
    """A plain `RbstudyError` (an --out its file system refuses) printed a path's newline as
    it is: two lines."""
    config = write_study(tmp_path, name="top")
    assert main(["sweep", str(config), "--out", "/proc/x\ny"]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("rbstudy: error: --out /proc/x\\ny: "), error


# A path given where a verb reads a file, as the test makes it in tmp_path (None: as it is).
NOT_A_FILE = {
    "folder": (lambda path: path.mkdir(), "it is a folder, not a regular file"),
    "/dev/null": (None, "it is a character device, not a regular file"),
    "missing": (lambda path: None, "No such file or directory"),
}


@pytest.mark.parametrize("kind", NOT_A_FILE)
@pytest.mark.parametrize("verb", ["sweep", "sweep --cluster", "validate"])
def test_a_config_or_cluster_file_that_is_no_file_is_one_line(tmp_path, capsys, verb, kind):
    make, said = NOT_A_FILE[kind]
    path = tmp_path / "given.yaml"
    if make is None:
        path = pathlib.Path(kind)
    else:
        make(path)
    command, *option = verb.split()
    files = [str(write_study(tmp_path, name="top"))] if option else []
    out = tmp_path / "out"
    assert main([command, *files, *option, str(path), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured
    assert captured.err.startswith(f"rbstudy: error: {path}: cannot read the file: {said}; "), captured.err
    assert not out.exists()


# An --out that is no folder, as the test makes it in tmp_path (None: as it is).
NOT_A_FOLDER = {
    "/dev/null": (None, "is a file, not a folder"),
    "a file": (lambda path: path.write_text("x"), "is a file, not a folder"),
    "under a file": (lambda path: path.write_text("x"), "lies under the file"),
}


@pytest.mark.parametrize("kind", NOT_A_FOLDER)
@pytest.mark.parametrize("verb", ["sweep", "validate", "plot", "report", "conformance"])
def test_an_out_that_is_no_folder_is_one_line(tmp_path, capsys, verb, kind):
    """validate said "ok" of an --out its sweep refuses (a file, /dev/null)."""
    make, said = NOT_A_FOLDER[kind]
    out = pathlib.Path(kind) if make is None else tmp_path / "taken"
    if make is not None:
        make(out)
    out = out / "results" if kind == "under a file" else out
    given = {
        "sweep": [str(write_study(tmp_path, name="top"))],
        "validate": [str(write_study(tmp_path, name="top"))],
        "plot": ["x.nc"],
        "report": ["x.nc"],
        "conformance": ["--cases", "x"],
    }[verb]
    assert main([verb, *given, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured
    assert captured.err.startswith(f"rbstudy: error: --out {out}: {said}"), captured.err


def test_verify_names_a_digest_that_is_no_file_and_never_waits_on_it(tmp_path):
    """A part's digest (``<part>.nc.sha256``) that was a FIFO hung `verify` (and a sweep
    reusing the part) on opening it, a link to /dev/zero read it until the memory ran out,
    and a folder was called "damaged: its bytes do not match"."""
    makers = {
        "fifo": os.mkfifo,
        "zero": lambda path: path.symlink_to("/dev/zero"),
        "folder": lambda path: path.mkdir(),
    }
    parts = []
    for name, make in makers.items():
        part = tmp_path / f"{name}.nc"
        part.write_bytes(b"\x89HDF\r\n\x1a\n")
        make(tmp_path / f"{name}.nc.sha256")
        parts.append(str(part))
    # a process of its own: one that waits is ended (subprocess.run kills it at the timeout)
    done = subprocess.run(
        [sys.executable, "-m", "rbstudy", "verify", *parts], capture_output=True, text=True, timeout=60
    )
    error = done.stderr
    assert done.returncode == 1 and done.stdout == ""
    kinds = ("a FIFO (named pipe)", "a character device", "a folder")
    assert error.splitlines() == [
        f"rbstudy: error: {part}: cannot read its digest {pathlib.Path(part).name}.sha256: it is {kind}, "
        "not a regular file; remove it and rerun its sweep: the part is recomputed"
        for part, kind in zip(parts, kinds, strict=True)
    ]


def _closed_port():
    """A TCP port of this machine on which nothing listens (bound, then let go)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.parametrize(
    "where, said",
    [
        ({"cluster": {"options": {"threds_per_worker": 2}}}, "options.threds_per_worker: no keyword"),
        ({"cluster": {"options": {"threads_per_worker": -1}}}, "options.threads_per_worker: expected"),
        ({"scheduler": "nonsense"}, "--scheduler nonsense: not a scheduler address (missing port number"),
        ({"scheduler": "closed"}, ": cannot connect (Connection refused); start the cluster first"),
    ],
)
def test_a_bad_cluster_or_scheduler_is_refused_before_the_forecast(tmp_path, capsys, where, said):
    """Both printed the study's forecast first, and the error once the cluster was started
    or reached ('--scheduler nonsense': a traceback, exit 70)."""
    config = write_study(tmp_path, name="small")
    if "cluster" in where:
        cluster = tmp_path / "cluster.yaml"
        cluster.write_text(yaml.safe_dump({"kind": "local", "jobs": 1, **where["cluster"]}))
        option = ["--cluster", str(cluster)]
    else:
        address = where["scheduler"]
        option = ["--scheduler", f"tcp://127.0.0.1:{_closed_port()}" if address == "closed" else address]
    assert main(["sweep", str(config), *option, "--out", str(tmp_path / "out")]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured
    assert captured.err.startswith("rbstudy: error: ") and said in captured.err, captured.err
    assert not (tmp_path / "out").exists()
