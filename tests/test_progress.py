"""What a user sees while rbstudy works: a first run announced before numba compiles, a bar
whose timer ticks between batches on a terminal, a start and an end line elsewhere."""

import io
import json
import os
import pty
import re
import select
import subprocess
import sys
import threading
import time

import pytest
from helpers import HOSTILE, HOSTILE_SHOWN, write_study

from rbstudy.archive.load import open_results
from rbstudy.pipeline import cluster, execute
from rbstudy.pipeline.cluster import dashboard_line
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import _show_compiling, run_study
from rbstudy.pipeline.progress import Progress, live_wanted
from rbstudy.schemes._ready import Compiling

# The share of a first run's time within which its announcement must reach stderr (issue
# 30): it comes before the compiling, which is most of that run (a bound in seconds failed
# on a loaded machine, where the imports before it took 3 s).
ANNOUNCED_WITHIN = 0.2
# How long a test waits for the bar's drawing thread to redraw (it does ten times a second).
REDRAW_WAIT = 10.0


class Terminal(io.StringIO):
    """A stream that says it is a terminal, and whose text another thread may read."""

    def __init__(self):
        super().__init__()
        self.lock = threading.Lock()

    def isatty(self):
        return True

    def write(self, text):
        with self.lock:
            return super().write(text)

    def text(self):
        with self.lock:
            return self.getvalue()


def _sweep(config, out, cache, *options):
    """``rbstudy sweep`` in a process of its own, stderr a pipe (not a terminal); its
    stderr lines, each with the seconds from the process's start to its arrival."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    env.pop("CI", None)
    started = time.monotonic()
    process = subprocess.Popen(
        [sys.executable, "-m", "rbstudy.cli", "sweep", str(config), "--out", str(out), *options],
        env=env,
        text=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    lines = [(time.monotonic() - started, line.rstrip("\n")) for line in process.stderr]
    assert process.wait() == 0, lines
    return lines


@pytest.fixture(scope="module")
def one_scheme(tmp_path_factory):
    """A study of one scheme, and a first sweep of it with an empty numba cache."""
    folder = tmp_path_factory.mktemp("first_run")
    config = write_study(
        folder, name="first", run={"scheme": "euler", "dt": 0.01}, sweep={"dt": [0.01, 0.005]}
    )
    cache = folder / "numba-cache"
    return config, folder, cache, _sweep(config, folder / "out", cache)


@pytest.mark.slow
def test_a_first_run_says_it_compiles_before_it_does(one_scheme):
    _, _, cache, lines = one_scheme
    announced = [
        (seconds, line) for seconds, line in lines if line.startswith("first: compiling 1 scheme first")
    ]
    assert len(announced) == 1, lines
    seconds, line = announced[0]
    assert seconds < ANNOUNCED_WITHIN * lines[-1][0], lines
    assert line.endswith(", once per machine")
    following = lines[lines.index(announced[0]) + 1][1]
    assert following == f"  and rbstudy version, into numba's cache {cache}"  # where it goes
    assert all(len(line) <= 100 for _, line in lines)


@pytest.mark.slow
def test_elsewhere_than_a_terminal_a_sweep_prints_a_start_and_an_end_line(one_scheme):
    config, folder, cache, _ = one_scheme
    # the cache warm now: nothing to compile, nothing to announce
    lines = [line for _, line in _sweep(config, folder / "out", cache, "--force")]
    assert len(lines) == 2, lines
    assert lines[0] == "first: 2 cases in 2 batches"
    # the counts are the result line's, on stdout: the end line only closes the run
    assert re.fullmatch(r"first: done in [\d.]+ s", lines[1]), lines
    assert _sweep(config, folder / "out", cache, "--force", "--quiet") == []


def test_the_bar_ticks_while_no_batch_ends(monkeypatch):
    """The elapsed time on the terminal grows between two looks while the work stands
    still: the bar is redrawn by its own thread, not when a batch ends."""
    monkeypatch.delenv("CI", raising=False)  # CI runs this test too: its bar is off there
    terminal, now = Terminal(), [0.0]
    with Progress("study", "4 cases", stream=terminal, clock=lambda: now[0]) as progress:
        assert progress.live
        progress.phase("study: running batches", 4, "cases")
        progress.advance(1)  # one batch done; none after it
        for seconds in (1.5, 2.5):
            now[0] = seconds
            deadline = time.monotonic() + REDRAW_WAIT
            while f"1/4 cases {seconds:5.1f} s" not in terminal.text():
                assert time.monotonic() < deadline, terminal.text()[-300:]
                time.sleep(0.05)
    assert "study: running batches" in terminal.text()
    assert "~8 s left" in terminal.text()  # 1 case in 2.5 s, 3 to go: rate and time left


def test_no_bar_in_ci_or_when_quiet(monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    assert live_wanted(False, Terminal())
    assert not live_wanted(True, Terminal())
    assert not live_wanted(False, io.StringIO())
    monkeypatch.setenv("CI", "true")
    assert not live_wanted(False, Terminal())
    stream = Terminal()
    with Progress("study", "4 cases", stream=stream):
        pass  # work refused before its first phase: its one error line alone, no start
    assert stream.getvalue() == ""
    with Progress("study", "4 cases", stream=stream) as progress:
        progress.phase("study: running batches", 4, "cases")
        progress.advance(4)
        progress.end = "4 cases done"
    lines = stream.getvalue().splitlines()
    assert lines[0] == "study: 4 cases" and lines[1].startswith("study: 4 cases done in ")
    assert len(lines) == 2


@pytest.mark.parametrize("stream", (Terminal, io.StringIO))
def test_its_text_is_shown_as_text(monkeypatch, stream):
    """Words from a config or an archive (a study's or a scheme's name) are shown: a
    terminal's control sequences escaped, rich's markup and emoji codes as typed. On a
    terminal rich draws with control sequences of its own: none of the words' is there."""
    monkeypatch.delenv("CI", raising=False)
    stream, words = stream(), f"{HOSTILE} [bold]x[/bold] :smile:"
    with Progress(words, "4 cases", stream=stream) as progress:
        progress.phase(f"phase {words}", 4, "cases")
        progress.update(f"update {words}")
        progress.say(f"said {words}")
        time.sleep(0.3)  # a redraw or two on a terminal
    text = stream.getvalue()
    own = isinstance(stream, Terminal)  # rich's: ESC [ 2K, \r and so on
    for part in ("\x1b]0;pwned", "\x07", "\x1b[2J", "\x9b", "\x7f", *(() if own else ("\x1b", "\r"))):
        assert part not in text, repr(text[-300:])
    assert f"said {HOSTILE_SHOWN} [bold]x[/bold] :smile:" in text
    if own:  # the bar's words, drawn before it was erased
        assert f"update {HOSTILE_SHOWN[:20]}" in text
    else:
        assert text.startswith(f"{HOSTILE_SHOWN} [bold]x[/bold] :smile:: 4 cases\n")


def test_compiling_shows_the_schemes_done_and_no_time_left(monkeypatch):
    """Compiling children end schemes in bunches: one done after 60 s of 4 forecast "~180 s
    left" from the rate so far (issue 41 met "~599 s left" with ~60 s to go). The count is
    shown, and what compiles now; no time left where no compile of this machine was timed."""
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setattr(execute, "compile_seconds", dict)
    terminal, now = Terminal(), [0.0]
    with Progress("study", "4 cases", stream=terminal, clock=lambda: now[0]) as progress:
        _show_compiling(progress, "study", Compiling(4, 0, (), 2, "/cache"))
        now[0] = 60.0
        _show_compiling(progress, "study", Compiling(4, 1, ("rk4", "hht"), 2, "/cache"))
        deadline = time.monotonic() + REDRAW_WAIT
        while "1/4 schemes  60.0 s" not in terminal.text():
            assert time.monotonic() < deadline, terminal.text()[-300:]
            time.sleep(0.05)
    text = terminal.text()
    assert "study: compiling rk4, hht" in text
    assert "left" not in text and "/s" not in text, text[-300:]


class _Said:
    """A silent progress that records the words of its phases and updates."""

    def __init__(self):
        self.words = []

    def say(self, text):
        pass

    def phase(self, what, total=None, unit="", eta=True):
        self.words.append(what)

    def update(self, what=None, done=None):
        self.words.append(what)


def test_compiling_tells_the_time_left_by_what_each_scheme_took_the_last_time(monkeypatch):
    """The time left comes from the seconds each scheme took to compile on this machine the
    last time, not from the rate so far: the schemes not done shared by the processes, or the
    longest of them alone; and what they took now is kept for the next compile."""
    last = {"rk4": 20.0, "hht": 10.0, "euler": 6.0, "rkmk4": 40.0}
    kept = []
    monkeypatch.setattr(execute, "compile_seconds", lambda: last)
    monkeypatch.setattr(execute, "record_compile", kept.append)
    names = ("euler", "hht", "rk4", "rkmk4")
    said = _Said()
    _show_compiling(said, "study", Compiling(4, 0, (), 2, "/cache", names))
    _show_compiling(said, "study", Compiling(4, 1, ("rk4", "rkmk4"), 2, "/cache", names, (("euler", 5.0),)))
    took = (("euler", 5.0), ("hht", 9.0), ("rk4", 19.0))
    _show_compiling(said, "study", Compiling(4, 3, ("rkmk4",), 2, "/cache", names, took))
    _show_compiling(said, "study", Compiling(4, 4, (), 2, "/cache", names, (*took, ("rkmk4", 41.0))))
    assert said.words[:3] == [
        "study: ~40 s left, compiling 4 schemes",  # (6+10+20+40)/2 = 38 < 40
        "study: ~40 s left, compiling rk4, rkmk4",
        "study: ~40 s left, compiling rkmk4",
    ]
    assert kept == [{"euler": 5.0, "hht": 9.0, "rk4": 19.0, "rkmk4": 41.0}]
    # a scheme never timed is taken at the mean of those that were
    monkeypatch.setattr(execute, "compile_seconds", lambda: {"rk4": 20.0, "hht": 10.0})
    said = _Said()
    _show_compiling(said, "study", Compiling(3, 0, (), 1, "/cache", ("euler", "hht", "rk4")))
    assert said.words == ["study: ~45 s left, compiling 3 schemes"]


# Writes a mark on stderr when numpy is first imported: a child's site customisation.
_NUMPY_WATCH = """
import os, sys

class _Watch:
    def find_spec(self, name, path=None, target=None):
        if name == "numpy":
            sys.meta_path.remove(self)
            os.write(2, b"<numpy>")
        return None

sys.meta_path.insert(0, _Watch())
"""


def _on_terminal(argv, env=None):
    """``rbstudy argv`` in a process of its own, stderr a terminal (a pseudo-terminal),
    stdout a pipe: what the terminal got, and stdout."""
    main, child = pty.openpty()
    process = subprocess.Popen(
        [sys.executable, "-m", "rbstudy", *argv], stdout=subprocess.PIPE, stderr=child, env=env
    )
    os.close(child)
    shown = b""
    while True:
        ready, _, _ = select.select([main], [], [], 0.05)
        try:
            chunk = os.read(main, 65536) if ready else b""
        except OSError:  # the child's end closed
            break
        if ready and not chunk:
            break
        shown += chunk
        if not ready and process.poll() is not None:
            break
    out = process.stdout.read().decode()
    assert process.wait() == 0, shown
    os.close(main)
    return shown.decode(), out


@pytest.fixture(scope="module")
def small_archive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("summary")
    config = write_study(folder, name="small", sweep={"scheme": ["rk4", "hht"], "dt": [0.01, 0.005]})
    return run_study(load_study(config), folder / "out", quiet=True).path


@pytest.mark.slow
def test_a_first_line_before_the_libraries_load_then_the_summary_s_phases(small_archive, tmp_path):
    """Every verb was silent for 2-8 s under load while numpy, xarray and numba load, and
    summary for its whole run. On a terminal a first line comes before numpy is imported,
    and is erased; the summary's phases follow on stderr, its JSON alone on stdout."""
    (tmp_path / "sitecustomize.py").write_text(_NUMPY_WATCH)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    env.pop("CI", None)
    shown, out = _on_terminal(["summary", "--format", "json", str(small_archive)], env)
    first = "rbstudy summary: starting (loading its libraries) ..."
    assert shown.startswith(first + "<numpy>"), shown[:200]
    assert shown.index("\r\x1b[K") > shown.index("<numpy>")  # erased, once loaded
    cases = open_results(small_archive)["status"].size  # 2 schemes x 2 steps
    for phase in ("checking its checksums", f"reading its {cases} cases", "summary: computing the findings"):
        assert phase in shown, shown[-500:]
    assert json.loads(out)["study"] == "small"
    # elsewhere: stderr holds nothing (no line, no phases), stdout the same JSON
    piped = subprocess.run(
        [sys.executable, "-m", "rbstudy", "summary", "--format", "json", str(small_archive)],
        capture_output=True,
        text=True,
        env=env,
    )
    assert piped.stderr == "<numpy>" and piped.stdout == out


class _Client:
    """The two things `dashboard_line` asks of a distributed client."""

    def __init__(self, services):
        self.services = services
        self.dashboard_link = "http://127.0.0.1:8787/status"

    def scheduler_info(self, n_workers=-1):
        return {"services": self.services}


def test_the_dashboard_link_or_how_to_get_one(monkeypatch):
    monkeypatch.setattr(cluster, "_bokeh", lambda: True)
    assert dashboard_line(_Client({"dashboard": 8787})) == "dask dashboard at http://127.0.0.1:8787/status"
    assert dashboard_line(_Client({})) == "no dask dashboard: the scheduler runs none"
    # without bokeh the scheduler still names a dashboard, whose pages are empty
    monkeypatch.setattr(cluster, "_bokeh", lambda: False)
    assert (
        dashboard_line(_Client({"dashboard": 8787}))
        == "no dask dashboard: it needs bokeh; pip install 'rbstudy[dashboard]'"
    )


# A bar under way, in a process of its own, which ends as the CLI does on Ctrl-C.
_INTERRUPTED = """
import sys, time
from rbstudy.pipeline.progress import Progress
try:
    with Progress("study", "start") as progress:
        progress.phase("study: running batches", 4, "cases")
        time.sleep(60)
except KeyboardInterrupt:
    sys.stderr.write("\\nrbstudy: interrupted\\n")
"""


def _screen(raw, width):
    """The lines a terminal ``width`` columns wide shows after ``raw``: text with its
    wrap at the last column (made when the next character comes), carriage return, line
    feed, cursor up and erase line; other controls shown as nothing."""
    lines, row, col, wrap = [[]], 0, 0, False
    for token in re.findall(r"\x1b\[[?0-9;]*[A-Za-z]|.", raw.decode("utf-8", "replace"), re.S):
        if token.startswith("\x1b"):
            if token[-1] == "A":
                row, wrap = max(0, row - int(token[2:-1] or 1)), False
            elif token == "\x1b[2K":
                lines[row] = []
        elif token == "\r":
            col, wrap = 0, False
        elif token == "\n":
            row, wrap = row + 1, False
        elif token >= " ":
            if wrap:
                row, col, wrap = row + 1, 0, False
            lines += [[] for _ in range(row + 1 - len(lines))]
            lines[row] += [" "] * (col + 1 - len(lines[row]))
            lines[row][col] = token
            col, wrap = (col, True) if col == width - 1 else (col + 1, False)
        lines += [[] for _ in range(row + 1 - len(lines))]
    return ["".join(line).rstrip() for line in lines]


@pytest.mark.skipif(not hasattr(os, "fork"), reason="a pseudo-terminal needs POSIX")
def test_ctrl_c_leaves_no_frozen_bar_on_screen():
    """Ctrl-C in a terminal 100 columns wide: the terminal echoes "^C" after the bar, and
    the bar's line is erased with it, so the prompt follows on a clean screen (issue 41)."""
    import fcntl
    import pty
    import struct
    import termios

    width = 100
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 30, width, 0, 0))
    env = {**os.environ, "COLUMNS": str(width), "LINES": "30"}
    env.pop("CI", None)
    process = subprocess.Popen(
        [sys.executable, "-c", _INTERRUPTED],
        stdin=follower,
        stdout=follower,
        stderr=follower,
        env=env,
        start_new_session=True,  # the terminal's foreground: Ctrl-C reaches it alone
        preexec_fn=lambda: fcntl.ioctl(0, termios.TIOCSCTTY, 0),
    )
    os.close(follower)
    raw, sent = b"", False
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            chunk = os.read(leader, 65536)
        except OSError:  # the process ended and closed the terminal
            break
        if not chunk:
            break
        raw += chunk
        if not sent and raw.count(b"running batches") >= 3:  # drawn, and redrawn
            os.write(leader, b"\x03")  # Ctrl-C, as a user types it
            sent = True
    os.close(leader)
    assert process.wait(timeout=30) == 0 and sent, raw[-300:]
    assert b"^C" in raw  # the terminal echoed it
    shown = [line for line in _screen(raw, width) if line]
    assert shown == ["rbstudy: interrupted"], shown


def test_a_count_of_one_names_one_thing(tmp_path):
    """A study of one case says "1 case in 1 batch", its forecast likewise, and every count
    of the messages goes through one rule: "1 schemes" had an s appended to its count."""
    from rbstudy.pipeline.config import load_study
    from rbstudy.pipeline.estimate import describe, estimate
    from rbstudy.pipeline.execute import study_progress

    study = load_study(write_study(tmp_path, name="one"))
    assert study_progress(study).start == "1 case in 1 batch"
    assert describe(study, estimate(study)).startswith("one: 1 case (one case) in 1 batch, ")
    from rbstudy.errors import counted

    assert [counted(n, "scheme") for n in (0, 1, 2)] == ["0 schemes", "1 scheme", "2 schemes"]
    assert counted(1, "batch", "batches") == "1 batch" and counted(3, "batch", "batches") == "3 batches"
