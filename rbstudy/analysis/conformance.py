"""The conformance scorecard: each scheme judged on the golden set, from the archives alone.

`rbstudy conformance` sweeps the golden studies (`rbstudy.pipeline.golden`) and then judges
every scheme in every case by the rules that case names (`RULES`):

- ``order``: the observed order of the final orientation error is within `ORDER_TOLERANCE`
  of the scheme's nominal order. The observed order is the summary's fit over the
  asymptotic range (`rbstudy.analysis.summary`); where the golden steps leave no such range,
  it is the slope of the finest pair of neighbouring steps whose errors both lie between
  `EXACT` and `SLOPE_CEILING`. A scheme whose errors all stay at or below `EXACT`, without
  falling as the step shrinks (round-off grows with the steps), passes as exact.
- ``invariants``: every invariant the scheme claims (`claimed_invariants`) is kept below
  `rbstudy.analysis.summary.KEPT_TOLERANCE` in every case that finished.
- ``energy``: the rotational energy never exceeds its start by more than `ENERGY_GAIN`
  (relative), at any sample of any finished case. A scheme that loses energy passes; the
  cell's details give the largest loss too.
- ``flip``: the interval between flips of a body turning about its intermediate axis is
  within one time step of the exact one (or within `FLIP_FLOOR`, the measurement's floor),
  at every step of the sweep where the case finished; a finished case that never flips
  fails. Its number is the largest error in time steps.
- ``failure``: no case fails (blows up, or does not converge) at a step where one of the
  baseline finished: rbstudy's own schemes of the same nominal order (``scheme_origin``
  ``rbstudy``), which every golden study sweeps (`rbstudy.pipeline.golden.baseline`). A
  plug-in or engine scheme in the same run is never the yardstick, so a scheme's card does
  not depend on what else is judged; the details name the survivor.

A case taken from a peer's public tests carries the figure its source asserts
(`rbstudy.pipeline.golden.Figure`): every scheme is checked against it apart from the rules
(`judge_figure`, by the measures of `FIGURE_MEASURES`), at the case's own step, the source's;
the cell says ``figure yes`` or ``figure no``, and nothing where the source asserts no number
of that scheme (a figure that is one engine integrator's own output is asked of it alone).
Where a moment acts, the cell of a scheme that holds each step's loads over the step (an
engine adapter, `rbstudy.schemes.Scheme.loads_held`) is marked `HELD_LOAD_MARK`, and the
card says in a footnote (`HELD_LOAD_NOTE`) that it judges the adapter.

A cell passes when every rule of its case passes; its number is the observed order (none
for a scheme exact on the body). Every golden case sweeps ``dt`` alone, so a scheme's
cases in it are its time steps. `score_case` returns the cells;
`format_scorecard` prints them; `scorecard_dataset` is the archive of the scorecard
(``passed`` and ``value`` per scheme and case, and per rule); the page is
`rbstudy.analysis.card_page`'s.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from tabulate import tabulate

from rbstudy.analysis.summary import (
    ERROR_MEASURES,
    KEPT_TOLERANCE,
    TERMINAL_WIDTH,
    error_measure,
    per_scheme,
    scheme_rows,
    schemes_of,
    status_counts,
    status_text,
    wrap_clauses,
)
from rbstudy.errors import counted
from rbstudy.numerics.state import INVARIANTS, OK

if TYPE_CHECKING:
    import xarray as xr

    from rbstudy.pipeline.golden import Figure

__all__ = [
    "RULES",
    "ORDER_TOLERANCE",
    "ENERGY_GAIN",
    "SLOPE_CEILING",
    "ORIGIN_RBSTUDY",
    "FIGURE_MEASURES",
    "HELD_LOAD_MARK",
    "HELD_LOAD_NOTE",
    "Verdict",
    "Cell",
    "judge_figure",
    "score_case",
    "format_scorecard",
    "scorecard_dataset",
    "held_note",
    "tally_statuses",
    "status_lines",
]

ORDER_TOLERANCE = 0.3
ENERGY_GAIN = 1e-3
# A finest-pair slope is taken only through errors below this (rad): past it the error no
# longer shrinks as a power of dt.
SLOPE_CEILING = 0.5
# Errors at or below this at every step, not falling as the step shrinks: exact for this
# body (round-off, ~1e-16 rad a step, 1.4e-9 after 25,600 steps of exact_split on the
# T-handle); nor is a slope taken through an error below it.
EXACT = 1e-8
# The flip interval is measured between samples: errors below this (s) are its floor.
FLIP_FLOOR = ERROR_MEASURES["flip"].floor
# The `scheme_origin` of rbstudy's own schemes (`Scheme.origin`), the failure rule's baseline
ORIGIN_RBSTUDY = "rbstudy"
# What tabulate's plain table puts between two columns.
_GAP = "  "
# The card's footnote on a cell whose scheme holds the loads over each step under a moment
# (`rbstudy.schemes.Scheme.loads_held`): its order there is the adapter's, not the engine's.
HELD_LOAD_MARK = "*"
HELD_LOAD_NOTE = (
    f"{HELD_LOAD_MARK} the adapter holds the loads of each step's start over the "
    "step, as a caller hands them to the engine (docs/engines.md): where a moment "
    "acts, a cell so marked judges that, not the engine's integrator"
)
RULES = {
    "order": f"observed order within {ORDER_TOLERANCE} of the nominal order",
    "invariants": f"every claimed invariant kept below {KEPT_TOLERANCE:g} (finished cases)",
    "energy": f"energy never above its start by more than {ENERGY_GAIN:g} (relative)",
    "flip": "flip interval within one time step of the exact one",
    "failure": "no failure where one of rbstudy's builtin schemes of the same nominal order finished",
}


@dataclass(frozen=True)
class Verdict:
    """One rule on one scheme in one case: ``passed`` (None: does not apply), the measured
    ``value`` and a line of ``text``."""

    passed: bool | None
    value: float
    text: str


@dataclass(frozen=True)
class Cell:
    """A scheme in a case: ``passed`` (all applicable rules), its number ``value``, the
    ``verdicts`` per rule name, the ``figure`` verdict: whether the scheme reproduces the
    figure the case's source asserts (None: the source asserts none), and ``load_held``:
    the scheme holds each step's loads over the step in a case where a moment acts, so the
    cell judges its adapter (`HELD_LOAD_NOTE`)."""

    passed: bool
    value: float
    verdicts: dict[str, Verdict]
    figure: Verdict | None = None
    load_held: bool = False

    def short(self) -> str:
        """What the cell shows: the observed order of a scheme that passed (``order 4.00``),
        ``exact`` for one exact on the body, ``pass`` where no order is judged, or the rules
        it failed (``FAIL energy, failure``); then ``figure yes`` or ``figure no`` where the
        source asserts a figure; then `HELD_LOAD_MARK` where the load is held."""
        return (
            self._verdict()
            + ("" if self.figure is None else f", figure {'yes' if self.figure.passed else 'no'}")
            + (f" {HELD_LOAD_MARK}" if self.load_held else "")
        )

    def _verdict(self):
        if self.passed:
            if np.isfinite(self.value):
                return f"order {self.value:.2f}"
            return "exact" if "order" in self.verdicts else "pass"
        failed = [name for name, verdict in self.verdicts.items() if verdict.passed is False]
        return f"FAIL {', '.join(failed)}"


def _order(ds, scheme, row):
    errors = per_scheme(error_measure(ds, "orientation"), scheme)
    finished = per_scheme(ds["status"], scheme) == OK
    values = errors.where(finished).sortby("dt")  # finest first
    nominal = row["nominal"]
    series = values.values
    # exact: round-off at every step, growing as the steps shrink (a scheme of order 1 or
    # more falls fourfold over any three steps; this allows a halving at most)
    if np.all(series <= EXACT) and not series[-1] > 2 * series[0]:
        return Verdict(True, np.nan, "exact for this body: round-off at every step")
    if row["order"] is not None:
        low, high = row["order"]
        observed, how = 0.5 * (low + high), "fitted over the asymptotic range"
    else:
        dts = values["dt"].values
        usable = np.isfinite(series) & (series > EXACT) & (series < SLOPE_CEILING)
        pairs = [k for k in range(len(series) - 1) if usable[k] and usable[k + 1]]
        if not pairs:
            return Verdict(
                False,
                np.nan,
                f"no order shows at these steps (failed, at round-off, or errors past {SLOPE_CEILING} rad)",
            )
        k = pairs[0]  # the finest pair of neighbouring steps with usable errors
        observed = float(np.log(series[k + 1] / series[k]) / np.log(dts[k + 1] / dts[k]))
        how = f"the slope between dt = {dts[k]:g} and {dts[k + 1]:g} s"
    passed = nominal is not None and abs(observed - nominal) <= ORDER_TOLERANCE
    return Verdict(passed, observed, f"order {observed:.2f} ({how}), nominal {nominal}")


def _invariants(ds, scheme, row):
    claimed = str(per_scheme(ds["claimed_invariants"], scheme).values).split()
    claimed = [name for name in claimed if name != "none"]
    if not claimed:
        return Verdict(None, np.nan, "claims no invariant")
    if not bool((per_scheme(ds["status"], scheme) == OK).any()):
        return Verdict(None, np.nan, "no case finished")
    labels = [INVARIANTS[name] for name in claimed]
    lost = [label for label in labels if label not in row["kept"]]
    return Verdict(
        not lost,
        np.nan,
        f"claims {', '.join(labels)}; " + (f"lost {', '.join(lost)}" if lost else "all kept"),
    )


def _energy(ds, scheme, row):
    change = per_scheme(ds["energy_error"], scheme).where(per_scheme(ds["status"], scheme) == OK)
    if not bool(change.notnull().any()):
        return Verdict(None, np.nan, "no finished case")
    gain, loss = float(change.max()), float(-change.min())
    return Verdict(
        gain <= ENERGY_GAIN,
        gain,
        f"largest gain {max(gain, 0.0) + 0.0:.2g}, largest loss {max(loss, 0.0) + 0.0:.2g} (relative)",
    )  # + 0.0: no "-0"


def _flip(ds, scheme, row):
    errors = per_scheme(ds["flip_interval_error"], scheme)
    finished = (per_scheme(ds["status"], scheme) == OK).values
    if not finished.any():
        return Verdict(None, np.nan, "no case finished")
    dts = errors["dt"].values[finished]
    values = np.abs(errors.values[finished])
    if not np.all(np.isfinite(values)):
        return Verdict(False, np.nan, "a finished case never flipped")
    # in time steps; the flip times are placed between samples to ~1e-5 s at best
    steps = values / dts
    passed = bool(np.all((values <= dts) | (values <= FLIP_FLOOR)))
    return Verdict(
        passed,
        float(steps.max()),
        f"flip interval error up to {steps.max():.2g} time steps ({values.max():.2g} s)",
    )


def _failure(ds, scheme, row):
    status = ds["status"]
    failed = (per_scheme(status, scheme) != OK).values
    if not failed.any():
        return Verdict(True, 0.0, "no case failed")
    nominal = row["nominal"]
    # the yardstick is rbstudy's own builtin schemes: never an engine's, a plug-in's, nor a
    # published step's, which are judged by it (so a cell is the same whoever runs beside);
    # the registry imported here, when scoring, so that reading archives never loads numba
    from rbstudy.schemes import BUILTIN_GROUP, scheme_groups

    builtin = set(scheme_groups()[BUILTIN_GROUP])
    peers = [
        other
        for other in schemes_of(ds)
        if other != scheme
        and other in builtin
        and str(per_scheme(ds["scheme_origin"], other).values) == ORIGIN_RBSTUDY
        and int(per_scheme(ds["nominal_order"], other)) == nominal
    ]
    if not peers:
        return Verdict(
            None,
            float(failed.sum()),
            f"{_cases(failed.sum())} failed; no other rbstudy scheme of order {nominal} to compare with",
        )
    for peer in peers:
        survived = (per_scheme(status, peer) == OK).values
        if np.any(failed & survived):
            # the largest such step: dt ascends in the archive
            dt = float(ds["dt"].values[np.flatnonzero(failed & survived)[-1]])
            return Verdict(
                False,
                float(failed.sum()),
                f"{_cases(failed.sum())} failed; {peer} (order {nominal}) finished at dt = {dt:g} s",
            )
    return Verdict(
        True,
        float(failed.sum()),
        f"{_cases(failed.sum())} failed, where no "
        f"rbstudy scheme of order {nominal} finished ({', '.join(peers)})",
    )


def _cases(count):
    return counted(int(count), "case")


_JUDGES = {"order": _order, "invariants": _invariants, "energy": _energy, "flip": _flip, "failure": _failure}


def _rotational_energy(run):
    return 0.5 * (run["inertia"] * run["omega_body"] ** 2).sum("axis")


def _component(variable: str, axis: str) -> Callable[[xr.Dataset], xr.DataArray]:
    """The measure of the ``axis`` component of a run's ``variable``."""
    return lambda run: run[variable].sel(axis=axis)


# What a source's figure can be checked on, from one scheme's run at one step: name ->
# function of that run (an xarray dataset) giving a number, or one per saved time.
FIGURE_MEASURES: dict[str, Callable[[xr.Dataset], xr.DataArray]] = {
    # a cycle is a step and the start: Radioss counts cycles 0 to N
    "cycles": lambda run: run["n_steps"] + 1,
    "rotational_energy": _rotational_energy,  # J, in the principal axes
    "orientation_error": lambda run: run["orientation_error"],  # rad
    # rad/s; |w - w_exact| where |w_exact| stays |w(0)|: a symmetric top, a spherical body
    "omega_error_magnitude": lambda run: run["omega_error"] * run["initial_spin"],
    # a component of the angular velocity in space (rad/s) or of the centre's position (m)
    **{
        f"{variable}_{axis}": _component(variable, axis)
        for variable in ("omega_space", "position")
        for axis in "xyz"
    },
}


def judge_figure(ds: xr.Dataset, scheme: str, figure: Figure) -> Verdict:
    """Whether ``scheme`` reproduces ``figure`` (`rbstudy.pipeline.golden.Figure`) in the
    golden study ``ds``, at its largest step (the source's): a `Verdict` whose value is the
    largest deviation as a share of its allowance (1 at the edge)."""
    dt = float(ds["dt"].max())
    run = per_scheme(ds, scheme).sel(dt=dt)
    if int(run["status"]) != OK:
        return Verdict(False, np.nan, f"failed at dt = {dt:g} s")
    worst, said = 0.0, []
    for check in figure.checks:
        measured = FIGURE_MEASURES[check.measure](run)
        if check.at is not None:
            measured = measured.sel(time=check.at, method="nearest")
        times = measured["time"] if "time" in measured.dims else check.at or 0.0
        allowed = check.tolerance + check.growth * times
        deviation = np.abs(measured - check.expected)
        share = (
            float((deviation / allowed).max())
            if check.tolerance
            else float(np.inf if deviation.max() > 0 else 0.0)
        )
        worst = max(worst, share)
        allowance = (f" +- {check.tolerance:g}" if check.tolerance else "") + (
            f" + {check.growth:g} t" if check.growth else ""
        )
        farthest = float(measured.values.flat[int(np.argmax(deviation.values))])  # signed
        # six figures hide a miss of 1e-10 in -106.16651966442174: say the miss as well
        off = f"; off by {float(deviation.max()):.2g}" if check.expected and check.tolerance else ""
        said.append(
            f"{check.measure} {'up to ' if 'time' in measured.dims else ''}"
            f"{farthest:.6g} (asserted {check.expected:g}{allowance}{off})"
        )
    return Verdict(worst <= 1.0, worst, f"at dt = {dt:g} s: {'; '.join(said)}")


def score_case(
    ds: xr.Dataset,
    rules: Collection[str],
    schemes: Sequence[str] | None = None,
    figure: Figure | None = None,
    loads_held: Collection[str] = (),
) -> dict[str, Cell]:
    """The `Cell` of each of ``schemes`` (default: every scheme) of the golden study ``ds``
    under ``rules`` (names of `RULES`), checked against the source's ``figure`` where there
    is one and it is asked of the scheme (`Figure.scheme`); ``loads_held``: the schemes
    whose cells judge how their adapter holds the case's moment: scheme -> cell."""
    rows = {row["scheme"]: row for row in scheme_rows(ds)}
    cells = {}
    for scheme in schemes or schemes_of(ds):
        verdicts = {rule: _JUDGES[rule](ds, scheme, rows[scheme]) for rule in rules}
        order = verdicts.get("order")
        cells[scheme] = Cell(
            all(v.passed is not False for v in verdicts.values()),
            np.nan if order is None else order.value,
            verdicts,
            None
            if figure is None or figure.scheme not in (None, scheme)
            else judge_figure(ds, scheme, figure),
            scheme in loads_held,
        )
    return cells


def tally_statuses(
    tally: dict[int, dict[str, int]], ds: xr.Dataset, schemes: Sequence[str]
) -> dict[int, dict[str, int]]:
    """Add the failed cases of ``schemes`` in the golden study ``ds`` to ``tally`` (status
    code -> scheme -> cases, summed over the golden cases); returns it."""
    for code, cases in status_counts(ds, schemes).items():
        counted = tally.setdefault(code, {})
        for scheme, count in cases.items():
            counted[scheme] = counted.get(scheme, 0) + count
    return tally


def status_lines(tally: Mapping[int, Mapping[str, int]]) -> list[str]:
    """A line per status of failed cases in ``tally`` (`tally_statuses`): the cases per
    scheme, what the status means and what to try, as the findings of a study say it."""
    return [status_text(code, cases) for code, cases in sorted(tally.items())]


def format_scorecard(cells: Mapping[str, Mapping[str, Cell]], cases: Sequence[str]) -> str:
    """The printed table: a row per scheme, a column per case (``cells``: case -> scheme ->
    `Cell`), and the count of cases passed; the cases in as many blocks under each other as
    keep every line within `TERMINAL_WIDTH`; then `HELD_LOAD_NOTE` if a cell is so marked."""
    schemes = list(dict.fromkeys(s for case in cases for s in cells[case]))
    passed = [f"{sum(cells[c][s].passed for c in cases if s in cells[c])}/{len(cases)}" for s in schemes]
    columns = {c: [c, *(cells[c][s].short() if s in cells[c] else "-" for s in schemes)] for c in cases}
    fixed = [["scheme", *schemes], ["passed", *passed]]

    def width(column):
        return max(map(len, column)) + len(_GAP)

    start = sum(map(width, fixed)) - len(_GAP)  # no gap before the first column
    blocks: list[list[str]] = [[]]
    used = start
    for case in cases:
        if blocks[-1] and used + width(columns[case]) > TERMINAL_WIDTH:
            blocks.append([])
            used = start
        blocks[-1].append(case)
        used += width(columns[case])
    return "\n\n".join(
        [
            tabulate(
                list(zip(*fixed, *(columns[c] for c in block), strict=True)),
                tablefmt="plain",
                colalign=["left", "right"] + ["left"] * len(block),
                disable_numparse=True,
            )
            for block in blocks
        ]
        + (["\n".join(wrap_clauses(HELD_LOAD_NOTE, indent="  "))] if held_note(cells, cases) else [])
    )


def held_note(cells: Mapping[str, Mapping[str, Cell]], cases: Sequence[str]) -> str | None:
    """`HELD_LOAD_NOTE` where a cell of ``cases`` judges an adapter's held load
    (`Cell.load_held`), else None."""
    return HELD_LOAD_NOTE if any(cell.load_held for case in cases for cell in cells[case].values()) else None


@dataclass(frozen=True)
class _CardArrays:
    """The scorecard's values over (scheme, case), and over (scheme, case, rule) for the
    ``rule_`` ones, as `scorecard_dataset` stores them (-1, NaN and "" where not run, not
    applicable or not asserted)."""

    passed: np.ndarray
    value: np.ndarray
    rule_passed: np.ndarray
    rule_value: np.ndarray
    rule_text: np.ndarray
    figure: np.ndarray
    figure_value: np.ndarray
    figure_text: np.ndarray


def _card_arrays(cells, cases, schemes, rules):
    """The `_CardArrays` of ``cells`` (case -> scheme -> `Cell`) over ``schemes``, ``cases``
    and ``rules``."""
    cards, judged = (len(schemes), len(cases)), (len(schemes), len(cases), len(rules))
    arrays = _CardArrays(
        passed=np.full(cards, -1, dtype=np.int8),
        value=np.full(cards, np.nan),
        rule_passed=np.full(judged, -1, dtype=np.int8),
        rule_value=np.full(judged, np.nan),
        rule_text=np.full(judged, "", dtype=object),
        figure=np.full(cards, -1, dtype=np.int8),
        figure_value=np.full(cards, np.nan),
        figure_text=np.full(cards, "", dtype=object),
    )
    for i, s in enumerate(schemes):
        for j, c in enumerate(cases):
            cell = cells[c].get(s)
            if cell is None:
                continue
            arrays.passed[i, j], arrays.value[i, j] = cell.passed, cell.value
            if cell.figure is not None:
                arrays.figure[i, j], arrays.figure_value[i, j] = cell.figure.passed, cell.figure.value
                arrays.figure_text[i, j] = cell.figure.text
            for k, rule in enumerate(rules):
                verdict = cell.verdicts.get(rule)
                if verdict is not None:
                    arrays.rule_passed[i, j, k] = -1 if verdict.passed is None else verdict.passed
                    arrays.rule_value[i, j, k], arrays.rule_text[i, j, k] = verdict.value, verdict.text
    return arrays


def _flags(meanings):
    """The attributes of a flag variable of -1, 0 and 1, named by ``meanings``."""
    return {"flag_values": np.array([-1, 0, 1], dtype=np.int8), "flag_meanings": meanings}


# The scorecard archive's variables, in order: name -> (dimensions, attributes); the values
# are the `_CardArrays` field of the same name.
_CARD_VARIABLES = {
    "passed": (
        ("scheme", "case"),
        {"long_name": "the scheme passed every rule of the case", **_flags("not_run fail pass")},
    ),
    "value": (("scheme", "case"), {"long_name": "observed order of the final orientation error"}),
    "rule_passed": (
        ("scheme", "case", "rule"),
        {"long_name": "the scheme passed the rule", **_flags("not_applicable fail pass")},
    ),
    "rule_value": (
        ("scheme", "case", "rule"),
        {
            "long_name": "the rule's measured number: the observed order, the "
            "largest relative energy gain, the largest flip "
            "interval error in time steps, the failed cases"
        },
    ),
    "rule_text": (("scheme", "case", "rule"), {"long_name": "what was measured"}),
    "figure": (
        ("scheme", "case"),
        {
            "long_name": "the scheme reproduces the figure the source asserts",
            **_flags("not_asserted no yes"),
        },
    ),
    "figure_value": (
        ("scheme", "case"),
        {"long_name": "largest deviation from the figure, share of allowed"},
    ),
    "figure_text": (("scheme", "case"), {"long_name": "what was measured against the figure"}),
}


def scorecard_dataset(
    cells: Mapping[str, Mapping[str, Cell]], cases: Sequence[str], attrs: Mapping[str, Any]
) -> xr.Dataset:
    """The scorecard as an xarray dataset over (scheme, case) and (scheme, case, rule):
    ``passed`` (1 pass, 0 fail; -1 where a rule does not apply), ``value`` and the rules'
    texts, with ``attrs`` (provenance) and each rule's meaning."""
    import xarray as xr

    schemes = list(dict.fromkeys(s for case in cases for s in cells[case]))
    rules = list(RULES)
    arrays = _card_arrays(cells, cases, schemes, rules)
    return xr.Dataset(
        {
            name: (dims, getattr(arrays, name), dict(attributes))
            for name, (dims, attributes) in _CARD_VARIABLES.items()
        },
        coords={
            "scheme": np.array(schemes, dtype=object),
            "case": np.array(cases, dtype=object),
            "rule": np.array(rules, dtype=object),
            "rule_meaning": ("rule", np.array([RULES[r] for r in rules], dtype=object)),
        },
        attrs=attrs,
    )
