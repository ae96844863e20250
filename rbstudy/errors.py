"""Errors a user can cause. The CLI prints them in one line and exits non-zero.

An `InputError` is structured: where (the file, the key path), what is wrong (naming the value
received) and the fix. It prints as ``<file>: <key>: <message>; <fix>``. Code that does not
know the file or the key (a scheme's option parser, the time-step check) raises it without
them, and the caller that does places it with `InputError.located`, so that no message is
ever rewritten as text.

Text from a file (a config's key, an archive's attribute, a plug-in's scheme name) may hold
the control characters a terminal obeys (ESC starts the sequences that clear the screen or
set the window's title): `printable` shows them as escapes, and every error prints so.

`counted` says a count with its noun (``1 scheme``, ``2 schemes``), for every message of
every layer above: "1 schemes" was an s appended to a count.
"""

from __future__ import annotations

import difflib
import os
import re
from collections.abc import Iterable
from typing import Any

__all__ = [
    "RbstudyError",
    "InputError",
    "SceneError",
    "ConfigError",
    "SchemeError",
    "MAX_LENGTH",
    "one_line",
    "did_you_mean",
    "printable",
    "counted",
]

# An error is one line a terminal can show: longer ones (a value of 90,000 items) are cut.
MAX_LENGTH = 1000
# How alike a name must be to a valid one to be offered as what was meant (difflib's ratio:
# 'hhtt' and 'hht' 0.86, 'duraton' and 'duration' 0.93, 'sweep' and 'bench' 0.2).
SIMILAR_NAME = 0.75
# What a terminal acts on rather than shows: the C0 controls but the line's own newline and
# tab, DEL, and the C1 controls (U+009B is a CSI as ESC [ is).
_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """``text`` with each control character a terminal would act on shown as Python
    writes it in a string's repr (``\\x1b``, ``\\x9b``, ``\\r``)."""
    return _CONTROL.sub(lambda match: repr(match[0])[1:-1], text)


def counted(number: int | str, noun: str, plural: str | None = None) -> str:
    """``1 scheme``, ``2 schemes``, ``0 batches`` (``plural``: the noun's plural where it is
    not the noun and an s); ``number`` as given (an int, or a text such as ``1,000``)."""
    return f"{number} {noun if str(number) == '1' else plural or noun + 's'}"


def did_you_mean(name: object, valid: Iterable[object]) -> str:
    """`` (did you mean 'hht'?)`` when ``name`` is a slip of one of ``valid``, else ''."""
    close = difflib.get_close_matches(str(name), [str(v) for v in valid], n=1, cutoff=SIMILAR_NAME)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _as_line(text: str) -> str:
    """``text`` as one printable line: its newlines shown as ``\\n`` (a path or a key may
    hold one), its other controls as `printable` shows them."""
    return printable(text.replace("\n", "\\n"))


class RbstudyError(Exception):
    """Base class of all expected, user-caused failures; its text is one `printable` line."""

    def __str__(self) -> str:
        return _as_line(super().__str__())


class InputError(RbstudyError):
    """A bad input value: ``source`` (file) and ``key`` (path) where, ``message``, ``fix``.

    Either place may be None while unknown; `located` fills them in. ``row`` is the scene of
    a table (`rbstudy.physics.scenes.SceneTable`) the bad value belongs to, for the sweep to
    name the case; None for a single value.
    """

    def __init__(
        self,
        message: str,
        fix: str | None = None,
        source: str | os.PathLike[str] | None = None,
        key: str | None = None,
        row: Any = None,
    ) -> None:
        self.message, self.fix, self.source, self.key = message, fix, source, key
        self.row = row
        super().__init__(str(self))

    def __str__(self) -> str:
        """One line, of bounded length: a key may hold a newline, a value may be huge."""
        text = self.message if not self.fix else f"{self.message}; {self.fix}"
        line = ": ".join(str(part) for part in (self.source, self.key, text) if part)
        line = _as_line(line)
        return line if len(line) <= MAX_LENGTH else f"{line[: MAX_LENGTH - 30]} ... (cut)"

    def located(
        self,
        source: str | os.PathLike[str] | None = None,
        key: str | None = None,
        kind: type[InputError] | None = None,
    ) -> InputError:
        """The same error placed in ``source`` under ``key``, as a ``kind`` (default: its own
        class). An outer key path is prefixed to the error's own (``sweep (dt[1] = 0.003):
        scene.body.mass``); a source the error already names is kept (it is the more specific
        file, such as a table the config refers to)."""
        if key and self.key:
            key = f"{key}: {self.key}"
        return (kind or type(self))(self.message, self.fix, self.source or source, key or self.key, self.row)


class SceneError(InputError):
    """A scene description is malformed or non-physical."""


class ConfigError(InputError):
    """A study configuration is malformed."""


class SchemeError(InputError):
    """An unknown scheme, an unknown scheme option, or an option value out of range."""


def one_line(error: BaseException) -> str:
    """A foreign exception's message whole, its lines joined into one, or its class name
    when it has none: what a one-line error quotes of it. Not its first line alone: a
    library's first line may end in "see:" or "for example:", the rest on the next."""
    return " ".join(str(error).split()) or type(error).__name__
