"""What a user sees while rbstudy works: a first run announced before numba compiles, a bar
whose timer ticks between batches on a terminal, a start and an end line elsewhere."""

import io
import os
import re
import subprocess
import sys
import threading
import time

import pytest
from conftest import HOSTILE, HOSTILE_SHOWN, write_study

from rbstudy.pipeline import cluster
from rbstudy.pipeline.cluster import dashboard_line
from rbstudy.pipeline.progress import Progress, live_wanted

# Seconds within which the first run's announcement must reach stderr (issue 30).
ANNOUNCED_WITHIN = 2.0
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
    assert seconds < ANNOUNCED_WITHIN, lines
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
