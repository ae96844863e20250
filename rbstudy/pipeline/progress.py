"""What a verb is doing, on stderr: the one progress display of sweep, plot, report,
conformance and bench, drawn by rich.

On a terminal a line that rich redraws ten times a second from a thread of its own, so that
its timer ticks while a batch or a figure is under way, not only when one ends: the phase
(``abaqus_top: running batches``), a bar, done/total in the phase's unit, the elapsed time,
the rate and the time left; a phase without a total shows a spinner and its elapsed time.
The line is erased when the work ends: the verb's own result line follows on stdout.
Elsewhere (a pipe, a file, ``CI`` set) a start line and an end line, nothing between; with
``--quiet`` nothing. The start line waits for the work's first phase, so that input refused
before it (an archive that is not one) is told in its one error line alone. Lines that
must be read (the first run's compile notice) are `say`-ed in all but the quiet case.
All of its text is shown as text: made `printable` (a study's or a scheme's name may hold
the control characters a terminal obeys), never read as rich's markup or emoji codes.

rich rather than tqdm: rich's live display redraws itself on its own thread (tqdm redraws
when it is updated, so a ticking timer would be a thread of ours), has a spinner for phases
of unknown length, and prints lines above the bar without tearing it.
"""

from __future__ import annotations

import os
import shutil
import sys
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Literal, TextIO

from rich.console import Console
from rich.progress import BarColumn, ProgressColumn, SpinnerColumn, Task, TaskID, TextColumn
from rich.progress import Progress as LiveDisplay
from rich.table import Column
from rich.text import Text

from rbstudy.errors import printable

__all__ = ["Progress", "live_wanted", "WIDTH", "SILENT"]

# Users read rbstudy in terminals 100 columns wide: the bar never takes more.
WIDTH = 100
# Columns the bar leaves free at the end of its line. A terminal echoes Ctrl-C as "^C" where
# the cursor is, after the bar: on a line drawn to the last column the echo wraps onto a new
# line, below the bar, and the bar rich erases on stopping is the one there, leaving the
# frozen bar above it on screen. With room for the two characters they stay on the bar's
# line, and are erased with it.
_ECHO_ROOM = 2
# Redraws per second: the elapsed time shows tenths.
_REDRAWS = 10
# The columns of the phase's words; longer words end in an ellipsis.
_WORDS = 50
# The displays drawing now, whose redrawing a fork waits for (`_hold_for_fork`).
_LIVE: list[LiveDisplay] = []
_LIVE_LOCK = threading.Lock()


def live_wanted(quiet: bool, stream: TextIO | None = None) -> bool:
    """Whether ``stream`` (stderr) gets a live bar: a terminal, not in CI, not ``quiet``."""
    stream = stream or sys.stderr
    return not quiet and stream.isatty() and not os.environ.get("CI")


class _Counts(ProgressColumn):
    """done/total unit, elapsed, rate and time left (unless the phase has no ``eta``); a
    phase without a total: elapsed only. The rate is done over elapsed, which falls while a
    slow batch runs, rather than rich's estimate from its last updates, which stands still
    between them."""

    def render(self, task: Task) -> Text:
        elapsed = task.elapsed or 0.0
        if task.total is None:
            return Text(f"{elapsed:5.1f} s")
        done, total = int(task.completed), int(task.total)
        text = f"{done}/{total} {task.fields.get('unit', '')} {elapsed:5.1f} s"
        if done and elapsed > 0 and task.fields.get("eta", True):
            rate = done / elapsed
            per_second = f"{rate:.0f}" if rate >= 100 else f"{rate:.3g}"
            text += f" {per_second}/s ~{(total - done) / rate:.0f} s left"
        return Text(text)


def _hold_for_fork() -> None:
    """Before a fork: wait for any redraw under way and hold off the next, so that the
    child never inherits a lock the drawing thread held (the figures fork their drawers)."""
    _LIVE_LOCK.acquire()
    for display in _LIVE:
        display.live._lock.acquire()


def _release_after_fork() -> None:
    for display in _LIVE:
        display.live._lock.release()
    _LIVE_LOCK.release()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(
        before=_hold_for_fork, after_in_parent=_release_after_fork, after_in_child=_release_after_fork
    )


class Progress:
    """The progress of one piece of work named ``label`` (a study, an archive, the bench),
    a context manager: a live bar on a terminal (`live_wanted`), showing ``opening`` (words
    after the label) until the first `phase`; else ``label: start`` at the first `phase` and
    ``label: <end> in <s> s`` on a clean exit after it (`end`, "done" unless set); nothing
    when ``quiet``. ``clock`` (seconds) is rich's and the end line's clock."""

    def __init__(
        self,
        label: str,
        start: str,
        quiet: bool = False,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        opening: str | None = None,
    ):
        self.label, self.start, self.quiet, self.opening = label, start, quiet, opening
        self.stream = stream or sys.stderr
        self.clock = clock
        self.end = "done"
        self._display: LiveDisplay | None = None
        self._task: TaskID | None = None
        self._began = 0.0  # the clock as the work began: set on entering
        self._started = False

    @property
    def live(self) -> bool:
        """Whether the bar is being drawn (a terminal)."""
        return self._display is not None

    def __enter__(self) -> Progress:
        self._began = self.clock()
        if live_wanted(self.quiet, self.stream):
            columns = shutil.get_terminal_size((WIDTH, 24)).columns
            width = max(1, min(WIDTH, columns - _ECHO_ROOM))
            console = Console(
                file=self.stream,
                width=width,
                force_terminal=True,
                force_interactive=True,
                highlight=False,
                emoji=False,
            )
            self._display = LiveDisplay(
                SpinnerColumn(),
                TextColumn(
                    "{task.description}",
                    markup=False,
                    table_column=Column(no_wrap=True, overflow="ellipsis", max_width=_WORDS),
                ),
                BarColumn(bar_width=None, table_column=Column(ratio=1)),
                _Counts(table_column=Column(no_wrap=True)),
                console=console,
                refresh_per_second=_REDRAWS,
                transient=True,
                redirect_stdout=False,
                redirect_stderr=False,
                get_time=self.clock,
                expand=True,
            )
            words = self.label if self.opening is None else f"{self.label}: {self.opening}"
            self._task = self._display.add_task(printable(words), total=None, unit="")
            with _LIVE_LOCK:
                self._display.start()
                _LIVE.append(self._display)
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> Literal[False]:
        if self._display is not None:
            with _LIVE_LOCK:
                _LIVE.remove(self._display)
            self._display.stop()
            self._display = None
        elif kind is None and self._started and not self.quiet:
            self._line(f"{self.label}: {self.end} in {self.clock() - self._began:.1f} s")
        return False

    def phase(self, what: str, total: float | None = None, unit: str = "", eta: bool = True) -> None:
        """A new phase of the work, ``what`` (``abaqus_top: running batches``): the bar counts
        to ``total`` (None: a spinner) in ``unit``, from 0 and with its own timer. ``eta``:
        show the rate and the time left it gives, for units that each take about as long
        (the cases of a sweep); not for units that end in bunches after long silences (the
        schemes that child processes compile, whose rate so far forecast many times the
        wait), where the count is the honest news."""
        self._begin()
        # a task of its own: rich keeps a total once set
        if self._display is not None and self._task is not None:
            self._display.remove_task(self._task)
            self._task = self._display.add_task(printable(what), total=total, unit=unit, eta=eta)

    def update(self, what: str | None = None, done: float | None = None) -> None:
        """The phase's words and how much of it is done, as they change."""
        if self._display is not None and self._task is not None:
            self._display.update(
                self._task, description=None if what is None else printable(what), completed=done
            )

    def advance(self, amount: float = 1) -> None:
        """``amount`` more of the phase's total done."""
        if self._display is not None and self._task is not None:
            self._display.advance(self._task, amount)

    def say(self, text: str) -> None:
        """A line to read whatever the stream is (above the bar on a terminal), unless quiet;
        off a terminal after the start line."""
        self._begin()
        if self._display is not None:
            self._display.console.print(printable(text), markup=False, soft_wrap=True)
        elif not self.quiet:
            self._line(text)

    def echo(self, text: str) -> None:
        """A line of the verb's result (stdout), above the bar where both are on a terminal."""
        text = printable(text)
        if self._display is not None and sys.stdout.isatty():
            self._display.console.print(text, markup=False, soft_wrap=True)
        else:
            print(text, flush=True)

    def _begin(self) -> None:
        """The start line, off a terminal, before anything else this work prints."""
        if not self._started and self._display is None and not self.quiet:
            self._line(f"{self.label}: {self.start}")
        self._started = True

    def _line(self, text: str) -> None:
        self.stream.write(printable(text) + "\n")
        self.stream.flush()


# The progress of work nobody watches (a library call): says nothing, needs no ``with``.
SILENT = Progress("", "", quiet=True)
