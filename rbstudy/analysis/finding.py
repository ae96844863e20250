"""`Finding`: one statement about a study, the record every finding is
(`rbstudy.analysis.findings`, `rbstudy.analysis.flips`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["Finding"]


@dataclasses.dataclass(frozen=True, kw_only=True)
class Finding:
    """One statement about a study.

    kind: ``recommendation``, ``no_recommendation``, ``failure``, ``coincidence``,
    ``question``, ``verdict`` or ``flip``; text: the statement, one line; numbers: the values
    it states, by name (units in the names); cases: the cases it rests on, each a mapping of
    coordinate names to values (a coordinate not named: every value of it).
    """

    kind: str
    text: str
    numbers: dict[str, Any]
    cases: Sequence[Mapping[str, Any]]
