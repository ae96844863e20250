"""The study's answer in words: ranked findings read from its dataset (never from a rerun).

`findings(ds)` returns `Finding` records, most important first:

1. the recommendation: the cheapest scheme and step that meet the study's accuracy bound
   (the archive's per-case ``accuracy`` verdict: orientation error at every sample, energy and
   ``|L|`` drift), costed by the kernel time per case (`case_seconds`); one for the whole
   study, then one per distinct answer where the values of the other swept axes disagree, or
   a statement that no case meets the bound;
   then, where cases failed, one per status: the cases, what it means and what to try
   (`rbstudy.numerics.state.STATUSES`, as the scorecard says it);
2. coincidences: schemes whose final orientation errors agree to 3 digits in every case;
3. each scheme's verdict in one line, from `rbstudy.analysis.summary.scheme_rows`;
4. the study's own question, for every swept axis other than scheme and ``dt`` (a scheme
   option, a body parameter): the order and energy change per value where ``dt`` is swept,
   the accuracy verdicts per value where it is not. A scheme along which nothing changes is
   left to its verdict; a line wider than `MAX_LINE` is told a part a line.

Orders, invariants kept and the ``dt |w0|`` ranges are the summary's own: nothing here fits
or measures anything the table does not, so the words and the table cannot disagree.
"""

import dataclasses
import math
import textwrap
import typing
from collections.abc import Sequence

import numpy as np

from rbstudy.analysis.summary import (
    COINCIDENT_DIGITS,
    ERROR_MEASURES,
    FLOOR_WORDS,
    KEPT_TOLERANCE,
    NONE,
    SUMMARY_VARIABLES,
    coinciding_pairs,
    error_measure,
    floor_reason,
    format_table,
    order_text,
    orders_along,
    per_scheme,
    scheme_rows,
    schemes_of,
    status_counts,
    status_text,
    verdicts,
)
from rbstudy.archive.variables import ACCURATE
from rbstudy.numerics.state import INVARIANTS, OK, STATUS_NAMES

__all__ = [
    "Finding",
    "Recommendation",
    "findings",
    "recommendations",
    "table_records",
    "MAX_FINDING_LINES",
    "summary_document",
    "finding_lines",
    "markdown_summary",
    "csv_rows",
    "energy_rates",
    "FINDINGS_VARIABLES",
    "FINDINGS_REDUCED",
    "case_seconds",
    "calibrated",
    "EDGE_SHARE",
    "study_wide",
]

# What `findings` reads: the table's per-case scalars (the calibrated step cost among them),
# the energy series whose last value says whether a scheme gains or loses energy, and the
# cost's uncertainty, within which two costs are a tie.
FINDINGS_VARIABLES = (*SUMMARY_VARIABLES, "energy_error", "step_seconds_uncertainty")
# Of those, the time series the findings reduce along time, and how; read so
# (`rbstudy.archive.load.open_results`), a million cases' findings hold 16 MB of them, not 176 MB.
FINDINGS_REDUCED = {"momentum_error": "max", "energy_error": "last"}
# A recommended error within this share of the bound is at its edge, and said so: a step a
# little larger, or another body, may pass it (euler was recommended at 0.00995 rad against
# the default bound 0.01).
EDGE_SHARE = 0.01
# The findings a terminal shows before the table (text and md); the JSON form has them all.
MAX_FINDING_LINES = 12
# A list of values is named whole up to this many; a longer one as a range that loses none
# ("0.0001 to 10000, 17 values, every value swept", "all 17 values but 3.16": `_axis_text`).
_SHOWN_VALUES = 6
# A finding's line is at most this wide where it can be (a terminal of 100 columns): a
# question whose parts do not fit together is told in a line per part.
MAX_LINE = 100
_SWEPT_BY_SUMMARY = ("scheme", "dt")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Finding:
    """One statement about a study.

    kind: ``recommendation``, ``no_recommendation``, ``failure``, ``coincidence``,
    ``question`` or ``verdict``; text: the statement, one line; numbers: the values it states, by name (units
    in the names); cases: the cases it rests on, each a mapping of coordinate names to values
    (a coordinate not named: every value of it).
    """

    kind: str
    text: str
    numbers: dict
    cases: tuple


@dataclasses.dataclass(frozen=True, kw_only=True)
class Recommendation:
    """The cheapest accurate scheme and step for one value of the other swept axes.

    axes: those values (coordinate name -> value; empty when nothing else is swept);
    error: the case's final orientation error (rad); seconds_per_case: its kernel time
    (`case_seconds`); tied: the other (scheme, dt) whose cost is within the calibration's
    uncertainty of it (this one has the smallest error of them).
    """

    scheme: str
    dt: float
    error: float
    seconds_per_case: float
    axes: dict
    tied: tuple = ()


def _g(value, digits=3):
    """A number with ``digits`` significant digits, as text."""
    return f"{value:.{digits}g}"


def _plain(value):
    """A coordinate value as a JSON-friendly Python scalar."""
    value = value.item() if isinstance(value, np.generic) else value
    return str(value) if isinstance(value, bytes | np.str_) else value


def _other_dims(ds):
    return [d for d in ds["status"].dims if d not in _SWEPT_BY_SUMMARY]


def _label_values(ds, dim):
    """The labels of every position along ``dim``, name -> list of plain values: every
    coordinate that runs along ``dim`` alone (a zipped axis has several), else the
    position. Read once per axis: reading them per case took seconds a thousand cases."""
    names = [name for name, coord in ds.coords.items() if coord.dims == (dim,)]
    if not names:
        return {dim: list(range(ds.sizes[dim]))}
    return {name: [_plain(value) for value in ds[name].values] for name in names}


def _labels(ds, dim, index):
    """The coordinates of position ``index`` along ``dim`` (`_label_values`)."""
    return {name: values[index] for name, values in _label_values(ds, dim).items()}


def _label_text(labels):
    return ", ".join(f"{name}={_g(v) if isinstance(v, float) else v}" for name, v in labels.items())


class _Place(dict):
    """The coordinates of one value of the other swept axes (name -> value), as `_cases`
    yields them, which also know where they lie: ``positions`` (dim -> index) along
    ``axes`` (dim -> `_label_values` of that dim, every value swept), so that a list of them
    can be told without losing a value (`_where`). Elsewhere it is the plain mapping."""

    positions: dict = {}
    axes: dict = {}


def _where(labels):
    """Where a finding holds, every value of it (`_held`): ``inertia_ratio 0.5, 1.5, 2`` or
    ``inertia_ratio 0.0001 to 10000, 17 values, every value swept``, for the ``labels`` (a
    list of `_cases`' `_Place` mappings); a zipped axis's coordinates together
    (``spin/tilt 1/0, 2/0.5``), its index left out. Where the values held are not every
    combination of the axes' values held, it is told per value of the later axes
    (``alpha 0, -0.05 at inertia_ratio 1; alpha 0 at inertia_ratio 2``)."""
    axes = labels[0].axes if isinstance(labels[0], _Place) else {}
    if not axes:  # plain mappings: every value named
        return "; ".join(
            f"{name} " + ", ".join(dict.fromkeys(_text(label[name]) for label in labels))
            for name in labels[0]
        )
    return _held([tuple(label.positions[dim] for dim in axes) for label in labels], list(axes.items()))


def _held(positions, axes):
    """`_where`'s text of the held ``positions`` (tuples of indices along ``axes``, a list of
    (dim, `_label_values` of it)): per axis when they are every combination of the axes'
    values they hold, else the first axis's values per combination of the others."""
    first = sorted({p[0] for p in positions})
    if len(axes) == 1:
        return _axis_text(*axes[0], first)
    rests = {}
    for p in positions:
        rests.setdefault(p[1:], set()).add(p[0])
    groups = {}
    for rest, held in rests.items():
        groups.setdefault(tuple(sorted(held)), []).append(rest)
    if len(groups) == 1 and len(positions) == len(first) * len(rests):  # every combination
        return "; ".join([_axis_text(*axes[0], first), _held(list(rests), axes[1:])])
    return "; ".join(
        f"{_axis_text(*axes[0], list(held))} at {_held(rest, axes[1:])}" for held, rest in groups.items()
    )


def _axis_names(dim, axis):
    """The coordinates that name the values along ``dim`` (`_label_values` ``axis``): a zipped
    axis's own, its index (the dimension's name) left out."""
    return [name for name in axis if name != dim] or [dim]


def _value_texts(dim, axis):
    """Every value along ``dim`` as text, a zipped axis's coordinates joined by "/"."""
    names = _axis_names(dim, axis)
    return ["/".join(_text(axis[name][k]) for name in names) for k in range(len(axis[names[0]]))]


def _axis_text(dim, axis, held):
    """The values at positions ``held`` (sorted) along ``dim`` (`_label_values` ``axis``),
    none lost: each named when at most `_SHOWN_VALUES`; ``0.0001 to 10000, 17 values, every
    value swept``; ``all 17 values but 3.16``; or runs of neighbouring swept values, ``0.0001
    to 0.1, 1 (8 of the 17 values: every swept value of each range)``."""
    values = _value_texts(dim, axis)
    name = "/".join(_axis_names(dim, axis))
    count = len(values)
    if len(held) <= _SHOWN_VALUES:
        return f"{name} " + ", ".join(values[k] for k in held)
    if len(held) == count:
        return f"{name} {values[0]} to {values[-1]}, {count} values, every value swept"
    left = sorted(set(range(count)) - set(held))
    if len(left) <= _SHOWN_VALUES:
        return f"{name} all {count} values but " + ", ".join(values[k] for k in left)
    return (
        f"{name} {_runs(values, held)} ({len(held)} of the {count} values: every swept value of each range)"
    )


def _runs(values, held):
    """The ``values`` at positions ``held`` as runs of neighbours: ``a to b`` for three or
    more, ``a and b`` for two."""
    runs = []
    for k in held:
        if runs and k == runs[-1][-1] + 1:
            runs[-1].append(k)
        else:
            runs.append([k])
    return ", ".join(
        f"{values[run[0]]} to {values[run[-1]]}" if len(run) >= 3 else " and ".join(values[k] for k in run)
        for run in runs
    )


def _text(value):
    """A coordinate value as text: 3 significant digits, 3160 and 10000 rather than 3.16e+03
    and 1e+04."""
    if not isinstance(value, float):
        return str(value)
    return f"{float(_g(value)):.0f}" if 1e3 <= abs(value) < 1e6 else _g(value)


class _CaseLabels(Sequence):
    """The `_Place` of each value of the other swept axes, in C order (as `_cases` yields
    them), each made when it is read: a finding names a few of a million cases, whose
    mappings took 10 s to make."""

    def __init__(self, ds):
        self.dims = _other_dims(ds)
        self.shape = tuple(ds.sizes[d] for d in self.dims)
        self._labels_of = [_label_values(ds, dim) for dim in self.dims]
        self.axes = dict(zip(self.dims, self._labels_of, strict=True))

    def __len__(self):
        return math.prod(self.shape)

    def __getitem__(self, k):
        if not -len(self) <= k < len(self):
            raise IndexError(k)
        return self.at(tuple(int(i) for i in np.unravel_index(k % len(self), self.shape)))

    def at(self, index):
        """The `_Place` at ``index`` (a position along each of the other swept axes)."""
        labels = _Place()
        for values, k in zip(self._labels_of, index, strict=True):
            labels.update({name: column[k] for name, column in values.items()})
        labels.positions = dict(zip(self.dims, index, strict=True))
        labels.axes = self.axes
        return labels

    def where(self, members):
        """`_where` of the cases ``members`` (their indices, ascending), from their positions
        alone."""
        if not self.dims:
            return _where([self[k] for k in members])
        positions = np.column_stack(np.unravel_index(members, self.shape)).tolist()
        return _held(list(map(tuple, positions)), list(self.axes.items()))


class _Members(Sequence):
    """A finding's cases (`Finding.cases`): those of ``members`` (indices) among ``labels``
    (`_CaseLabels`), each mapping made when it is read, the ``fixed`` names (a scheme and a
    step) before its labels."""

    def __init__(self, labels, members, fixed=None):
        self._labels, self._members, self._fixed = labels, members, fixed

    def __len__(self):
        return len(self._members)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return tuple(self[i] for i in range(*k.indices(len(self))))
        labels = self._labels[int(self._members[k])]
        return labels if self._fixed is None else {**self._fixed, **labels}

    def __eq__(self, other):  # as the tuple of cases it stands for
        return isinstance(other, tuple | _Members) and tuple(self) == tuple(other)

    def __repr__(self):
        return f"_Members({len(self)} cases)"


def _cases(ds):
    """The cases of every value of the other swept axes, in C order: (labels, isel indexer)
    pairs, the labels a `_Place`."""
    labels = _CaseLabels(ds)
    for index in np.ndindex(*labels.shape):
        place = labels.at(index)
        yield place, dict(place.positions)


def calibrated(ds):
    """Whether ``ds`` costs its cases by the calibrated model (its ``step_seconds``: archives
    before it have none)."""
    return "step_seconds" in ds


def case_seconds(ds):
    """The kernel seconds of every case (the shape of ``status``): its steps (``n_steps``)
    times its run's calibrated seconds per body-step (``step_seconds``,
    `rbstudy.pipeline.calibration`), which no run's timer noise moves.

    An archive without ``step_seconds`` (older) is costed as it was: the steps at the
    scheme's seconds per step pooled over the swept ``dt`` (the summed ``run_time`` over the
    summed steps, at the same values of the other axes); one case's ``run_time`` of
    microseconds is mostly timer noise, and even pooled it changed the default study's
    recommendation between two runs."""
    steps = ds["n_steps"].broadcast_like(ds["status"]).astype(float)
    if calibrated(ds):
        return steps * ds["step_seconds"].broadcast_like(ds["status"])
    run_time = ds["run_time"].broadcast_like(ds["status"])
    if "dt" not in run_time.dims:
        return run_time
    return steps * (run_time.sum("dt") / steps.sum("dt"))


def _cost_uncertainty(ds):
    """The relative uncertainty of every case's `case_seconds`: its calibration's (0 where
    none is known: an older archive, a scheme costed at its declared figure)."""
    if "step_seconds_uncertainty" not in ds:
        return ds["status"].copy(data=np.zeros(ds["status"].shape))
    return ds["step_seconds_uncertainty"].broadcast_like(ds["status"]).fillna(0.0)


def _choose(seconds, uncertainty, error):
    """Per row of candidates (n, m): the cheapest, and those whose cost is within the
    calibration's uncertainty of it (their ranges overlap), a tie; the one of them with the
    smallest ``error`` (then the earliest) represents them. ``seconds`` is inf where a
    candidate does not meet the bound. Returns (pick (n,), tied (n, m))."""
    rows = np.arange(seconds.shape[0])
    cheapest = np.argmin(seconds, axis=1)
    least, spread = seconds[rows, cheapest][:, None], uncertainty[rows, cheapest][:, None]
    with np.errstate(invalid="ignore"):
        tied = np.isfinite(seconds) & (seconds * (1.0 - uncertainty) <= least * (1.0 + spread))
    ranked = np.where(tied, np.nan_to_num(error, nan=np.inf), np.inf)
    pick = np.where(tied.any(axis=1), np.argmin(ranked, axis=1), cheapest)
    return pick, tied


class _Picks(typing.NamedTuple):
    """The cheapest accurate (scheme, dt) of each of the n values of the other swept axes
    (C order), as columns: ``met`` (n,) whether any case there meets the bound; ``scheme``
    and ``dt`` (n,) the positions of the cheapest along those axes (0 where not swept, or
    nothing meets the bound); ``error`` (n,) its final orientation error (rad);
    ``seconds`` (n,) its kernel time (inf where nothing meets the bound); ``tied`` (n, m)
    the (scheme, dt) candidates in C order of equal cost (`_choose`); ``errors`` (n, m) every
    candidate's final orientation error (rad)."""

    met: np.ndarray
    scheme: np.ndarray
    dt: np.ndarray
    error: np.ndarray
    seconds: np.ndarray
    tied: np.ndarray
    errors: np.ndarray


def _picks(ds):
    """The `_Picks` of ``ds``, every value of the other axes at once. Cheapest: the least
    `case_seconds`, costs within their uncertainty a tie that the smaller error represents
    (`_choose`); then the earlier scheme, then the earlier dt (archive order: the smaller,
    as dt is stored ascending since rbstudy 0.4)."""
    order = [d for d in _SWEPT_BY_SUMMARY if d in ds["status"].dims]
    dims = [*_other_dims(ds), *order]

    def flat(value):  # (n, cases of one value of the other axes), in ``order``'s C order
        values = value.broadcast_like(ds["status"]).transpose(*dims).values
        return values.reshape(-1, math.prod(ds.sizes[d] for d in order))

    good = flat((ds["accuracy"] == ACCURATE) & (ds["status"] == OK))
    seconds = np.where(good, flat(case_seconds(ds)), np.inf)
    error = error_measure(ds, "orientation")
    errors = flat(error) if error is not None else np.full(seconds.shape, math.nan)
    cheapest, tied = _choose(seconds, flat(_cost_uncertainty(ds)), errors)
    shape = [ds.sizes[d] for d in order]
    position = dict(zip(order, np.unravel_index(cheapest, shape), strict=True)) if order else {}
    everywhere = np.arange(len(cheapest))
    zeros = np.zeros_like(cheapest)
    return _Picks(
        met=good.any(axis=1),
        scheme=position.get("scheme", zeros),
        dt=position.get("dt", zeros),
        error=errors[everywhere, cheapest],
        seconds=seconds[everywhere, cheapest],
        tied=tied,
        errors=errors,
    )


def _answer(ds, flat, order):
    """(scheme, dt) of the candidate at C-order position ``flat`` along ``order``."""
    shape = [ds.sizes[d] for d in order]
    at = dict(zip(order, np.unravel_index(flat, shape), strict=True)) if order else {}
    return (
        str(schemes_of(ds)[at.get("scheme", 0)]),
        float(np.atleast_1d(ds["dt"].values)[at.get("dt", 0)]),
    )


def recommendations(ds):
    """The cheapest accurate (scheme, dt) for every value of the other swept axes: a list of
    `Recommendation`, with None where no case of that value meets the bound (`_picks`)."""
    if "accuracy" not in ds:
        return []
    picks = _picks(ds)
    schemes = schemes_of(ds)
    dts = np.atleast_1d(ds["dt"].values)
    order = [d for d in _SWEPT_BY_SUMMARY if d in ds["status"].dims]
    return [
        Recommendation(
            scheme=str(schemes[scheme]),
            dt=float(dts[dt]),
            error=float(error),
            seconds_per_case=float(seconds),
            axes=labels,
            tied=tuple(
                other
                for other in (_answer(ds, k, order) for k in np.flatnonzero(tied))
                if other != (str(schemes[scheme]), float(dts[dt]))
            ),
        )
        if met
        else None
        for (labels, _), met, scheme, dt, error, seconds, tied, _ in zip(_cases(ds), *picks, strict=True)
    ]


class _Uniform(typing.NamedTuple):
    """The study-wide answer: (scheme, dt), its mean kernel seconds per case, its worst final
    orientation error (rad), and the other (scheme, dt) of equal cost (`_choose`)."""

    scheme: str
    dt: float
    seconds: float
    error: float
    tied: tuple


def study_wide(ds):
    """The cheapest (scheme, dt) that meets the bound in every case of the other axes, by
    total kernel time, costs within their uncertainty a tie that the smaller worst error
    represents: a `_Uniform`, or None."""
    order = [d for d in _SWEPT_BY_SUMMARY if d in ds["status"].dims]
    others = _other_dims(ds)
    meets = ((ds["accuracy"] == ACCURATE) & (ds["status"] == OK)).all(others)
    cost = case_seconds(ds).mean(others)
    seconds = np.where(meets.transpose(*order).values, cost.transpose(*order).values, np.inf).reshape(1, -1)
    if not np.isfinite(seconds).any():
        return None
    spread = _cost_uncertainty(ds).max(others).transpose(*order).values.reshape(1, -1)
    error = error_measure(ds, "orientation")
    worst = (
        error.max(others).transpose(*order).values.reshape(1, -1)
        if error is not None
        else np.full(seconds.shape, math.nan)
    )
    pick, tied = _choose(seconds, spread, worst)
    flat = int(pick[0])
    scheme, dt = _answer(ds, flat, order)
    return _Uniform(
        scheme=scheme,
        dt=dt,
        seconds=float(seconds[0, flat]),
        error=float(worst[0, flat]),
        tied=tuple(_answer(ds, k, order) for k in np.flatnonzero(tied[0]) if k != flat),
    )


def _choice_text(scheme, dt, tied):
    """``rk4 at dt=0.01 s``; with candidates of equal cost ``rk4 or rkmk4, equal cost, at
    dt=0.01 s`` (another dt named with its scheme)."""
    if not tied:
        return f"{scheme} at dt={_g(dt)} s"
    if all(other_dt == dt for _, other_dt in tied):
        return _alternatives([scheme, *(name for name, _ in tied)]) + f", equal cost, at dt={_g(dt)} s"
    return (
        _alternatives([f"{name} at dt={_g(step)} s" for name, step in ((scheme, dt), *tied)]) + ", equal cost"
    )


def _alternatives(names):
    """``a or b``, ``a, b or c``."""
    return ", ".join(names[:-1]) + f" or {names[-1]}"


def _at_edge(error, bound):
    return bool(bound is not None and math.isfinite(error) and error >= (1.0 - EDGE_SHARE) * bound)


def _error_text(error, bound, tail=None):
    """``error 2.8e-07 rad``, or at the bound's edge (`EDGE_SHARE`) ``error 0.00995 rad:
    within 1% of the bound 0.01``; with a ``tail`` (``", every case)"``), the bound follows
    the error (``error 2.8e-07 rad (bound 0.01, every case)``)."""
    if _at_edge(error, bound):
        return f"error {_g(error)} rad: within {EDGE_SHARE:.0%} of the bound {_g(bound)}" + (
            f" ({tail.removeprefix(', ')}" if tail and tail != ")" else ""
        )
    return f"error {_g(error)} rad" + (f" (bound {_g(bound)}{tail}" if tail is not None else "")


def _capped(ds, dt):
    """Whether ``dt`` is the largest step of a swept ``dt``: the grid, not the bound, may
    have stopped the answer there."""
    return bool("dt" in ds["status"].dims and ds.sizes["dt"] > 1 and dt == float(ds["dt"].max()))


def _capped_text(dt, short=False):
    """What a recommendation at the largest swept ``dt`` says; ``short`` for a per-value line,
    under the study-wide one that says it whole."""
    if short:
        return f"capped by the grid (dt={_g(dt)} s, the largest swept)"
    return (
        f"capped by the grid: dt={_g(dt)} s is the largest swept, a larger one may also meet the "
        "bound (widen sweep.dt, or sweep --find-step)"
    )


def _recommendation_numbers(ds, dt, seconds, error, bound, tied):
    """The numbers of a recommendation finding (units in the names)."""
    return {
        "dt_s": dt,
        "seconds_per_case": seconds,
        "error_rad": error,
        "accuracy_bound": bound,
        "equal_cost": [{"scheme": name, "dt_s": step} for name, step in tied],
        "capped_by_grid": _capped(ds, dt),
        "at_bound_edge": _at_edge(error, bound),
        "cost_model": "calibrated step_seconds" if calibrated(ds) else "run_time",
    }


def _recommendation_findings(ds):
    bound = ds.attrs.get("accuracy_bound")
    if "accuracy" not in ds:
        return [
            Finding(
                kind="no_recommendation",
                numbers={},
                cases=(),
                text="no recommendation: the archive has no accuracy verdict",
            )
        ]
    picks = _picks(ds)
    if not picks.met.any():
        return [
            Finding(
                kind="no_recommendation",
                numbers={"accuracy_bound": bound},
                cases=(),
                text=f"no scheme and step meet the accuracy bound {_g(bound)} in any case",
            )
        ]
    result = []
    # an older archive's costs move with its run's timer: said where the answer is
    uncalibrated = (
        ""
        if calibrated(ds)
        else "; costed by run_time, which moves between runs (sweep again to store calibrated step costs)"
    )
    uniform = study_wide(ds)
    if uniform is not None:
        everywhere = ", every case" if _other_dims(ds) else ""
        text = (
            f"recommended: {_choice_text(uniform.scheme, uniform.dt, uniform.tied)}, "
            f"{_g(uniform.seconds, 2)} s a case, {_error_text(uniform.error, bound, f'{everywhere})')}"
        )
        if _capped(ds, uniform.dt):
            text += "; " + _capped_text(uniform.dt)
        result.append(
            Finding(
                kind="recommendation",
                cases=({"scheme": uniform.scheme, "dt": uniform.dt},),
                numbers=_recommendation_numbers(
                    ds, uniform.dt, uniform.seconds, uniform.error, bound, uniform.tied
                ),
                text=text + uncalibrated,
            )
        )
    answers = len(np.unique(np.packbits(picks.tied[picks.met], axis=1), axis=0))  # of equal cost
    if uniform is None or answers > 1 or not picks.met.all():
        # grouped by answer (and its candidates of equal cost) as arrays; a dict per case
        # only for the finding's own cases (a million cases' Recommendation objects and
        # labels took ~600 MiB)
        labels = _CaseLabels(ds)
        order = [d for d in _SWEPT_BY_SUMMARY if d in ds["status"].dims]
        # grouped by the candidates of equal cost, not by the one that represents them at each
        # value: "euler or leapfrog" at one ratio and "leapfrog or euler" at the next are one
        # answer, told once
        tied = picks.tied & picks.met[:, None]
        keys = np.column_stack([picks.met, np.packbits(tied, axis=1)])
        _, first_of, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        group = group.reshape(-1)
        for first in np.sort(first_of):
            members = np.flatnonzero(group == group[first])
            where = labels.where(members)
            if not picks.met[first]:
                result.append(
                    Finding(
                        kind="no_recommendation",
                        numbers={"accuracy_bound": bound},
                        cases=_Members(labels, members),
                        text=f"no scheme and step meet the bound {_g(bound)} at {where}",
                    )
                )
                continue
            # the candidate with the smallest worst error over the group represents it
            candidates = np.flatnonzero(tied[first])
            worst = np.nan_to_num(picks.errors[np.ix_(members, candidates)], nan=np.inf).max(axis=0)
            chosen = candidates[int(np.argmin(worst))]
            answer = _answer(ds, chosen, order)
            tied_others = tuple(_answer(ds, k, order) for k in candidates if k != chosen)
            seconds = float(picks.seconds[members].max())
            error = float(picks.errors[members, chosen].max())
            text = (
                f"cheapest at {where}: {_choice_text(*answer, tied_others)}, {_g(seconds, 2)} s a case, "
                + _error_text(error, bound)
            )
            if _capped(ds, answer[1]):
                text += "; " + _capped_text(answer[1], short=uniform is not None and _capped(ds, uniform.dt))
            result.append(
                Finding(
                    kind="recommendation",
                    cases=_Members(labels, members, {"scheme": answer[0], "dt": answer[1]}),
                    numbers=_recommendation_numbers(ds, answer[1], seconds, error, bound, tied_others),
                    text=text,
                )
            )
    return result


def _failures(ds):
    """A finding per status of failed cases: how many of each scheme, what it means, what to
    try."""
    return [
        Finding(
            kind="failure",
            text=status_text(code, cases),
            numbers={"status": STATUS_NAMES[code], "cases": sum(cases.values())},
            cases=tuple({"scheme": scheme} for scheme in cases),
        )
        for code, cases in status_counts(ds).items()
    ]


def _coincidences(ds):
    error = error_measure(ds, "orientation")
    result = []
    for first, second in coinciding_pairs(ds, error):
        a, b = per_scheme(error, first).values, per_scheme(error, second).values
        both = np.isfinite(a) & np.isfinite(b)
        gap = float(np.max(np.abs(a - b)[both] / np.fmax(np.abs(a), np.abs(b))[both]))
        result.append(
            Finding(
                kind="coincidence",
                cases=({"scheme": first}, {"scheme": second}),
                numbers={"largest_relative_difference": gap, "cases": int(both.sum())},
                text=f"{second} gives {first}'s errors to {COINCIDENT_DIGITS} digits in "
                + (
                    f"all {int(both.sum())} cases (their lines overlap)"
                    if both.sum() > 1
                    else "the study's one case"
                ),
            )
        )
    return result


def energy_rates(ds):
    """The relative energy change per second of every case, (T_end - T0) / T0 / t_end, from
    the stored ``energy_error`` series or its last sample (read as `FINDINGS_REDUCED` says);
    None where the archive does not store it."""
    series = ds.get("energy_error")
    if series is None or "time" not in series.coords:
        return None
    last = series.isel(time=-1) if "time" in series.dims else series
    end = float(last["time"])
    rates = last / end
    rates.attrs["duration"] = end
    return rates


def _energy_text(rates, stable):
    """(the largest rate, ``loses energy, up to 0.0012/s``) over the ``stable`` cases, or
    (None, None) when their energy ends within `KEPT_TOLERANCE` of its start (kept)."""
    values = rates.values[stable]
    # a case that ends within round-off of its start energy neither gains nor loses
    values = values[np.abs(values) * rates.attrs["duration"] >= KEPT_TOLERANCE]
    if not values.size:
        return None, None
    largest = float(values[np.argmax(np.abs(values))])
    trend = "gains" if np.all(values > 0) else "loses" if np.all(values < 0) else "gains or loses"
    return largest, f"{trend} energy, up to {_g(abs(largest), 2)}/s"


def _row_scheme(row):
    return row["scheme"].split(",")[0]


def _verdict(ds, row, rates):
    name, numbers = row["scheme"], {}
    floor = ERROR_MEASURES["orientation"].floor
    largest = row.get("error")
    reason = floor_reason(row)
    if reason is not None:  # no order through errors at the floor (exact_split's "0.60")
        parts = [FLOOR_WORDS[reason]]
        if largest is not None:
            numbers["error_rad"] = largest
    elif row["order"] is None and largest is not None and np.isfinite(largest) and largest <= floor:
        parts = ["exact to round-off"]
        numbers["error_rad"] = largest
    elif row["order"] is not None:
        numbers["order_low"], numbers["order_high"] = row["order"]
        parts = [
            f"order {order_text(row)}"
            + (f" (nominal {row['nominal']})" if row["nominal"] is not None else "")
        ]
    else:
        parts = ["no order fitted"]
    if row["nominal"] is not None:
        numbers["nominal_order"] = row["nominal"]
    if np.isfinite(row["accurate_hw"]):
        numbers["accurate_up_to_dt_w0"] = row["accurate_hw"]
        parts.append(f"accurate to dt|w0| {_g(row['accurate_hw'])}")
    if row["invariants_measured"]:  # under a moment nothing is conserved, nor measured
        parts.append("keeps " + (", ".join(row["kept"]) or "none"))
    scheme = _row_scheme(row)
    if rates is not None and INVARIANTS["energy"] not in row["kept"]:
        status = per_scheme(ds["status"], scheme).values
        rate, text = _energy_text(per_scheme(rates, scheme), status == OK)
        if text:
            numbers["energy_rate_per_s"] = rate
            parts.append(text)
    if row["unstable"]:
        numbers["failed_cases"] = row["unstable"]
        start = f" from dt|w0| {_g(row['unstable_hw'])}" if np.isfinite(row["unstable_hw"]) else ""
        numbers["first_failed_dt_w0"] = row["unstable_hw"]
        parts.append(f"fails {row['unstable']}/{row['cases']}{start}")
    if row["radioss"]:
        numbers["past_radioss_limit"] = row["radioss"]
        parts.append(f"past Radioss limit {row['radioss']}/{row['cases']}")
    numbers["cases"] = row["cases"]
    return Finding(
        kind="verdict", text=f"{name}: " + "; ".join(parts), numbers=numbers, cases=({"scheme": scheme},)
    )


def _series(texts, values):
    """``texts``, one per value of an axis (``values``, its `_value_texts`), none lost: each
    in turn (``4.00, 4.00, 3.99``, in the order of the values the line names) where they are
    few or all differ, else each run of equal neighbours with the values it holds for, ``4.00
    at 0.0001 to 0.1, 3.99 at 0.316, none at 1 to 10000``."""
    runs = []
    for k, text in enumerate(texts):
        if runs and runs[-1][0] == text:
            runs[-1][1].append(k)
        else:
            runs.append((text, [k]))
    if len(texts) <= _SHOWN_VALUES or 2 * len(runs) > len(texts):
        return ", ".join(texts)
    return ", ".join(f"{text} at {_runs(values, held)}" for text, held in runs)


def _rows_along(ds, dim):
    """``scheme -> [row of scheme_rows(ds.isel({dim: k})) for each k]``: the first row of
    each scheme at each value along ``dim``. Where no swept option sets the order, only
    what `_questions` reads is computed, along ``dim`` at once: where ``dt`` is swept, the
    order fields (`orders_along`), else the case counts (cases, unstable, inaccurate,
    unjudged). A table per value took seconds for a thousand values, and the default
    study's findings 0.8 s for four."""
    composition = "nominal_order" in ds.coords and any(d != "scheme" for d in ds["nominal_order"].dims)
    if composition:
        per_value = [scheme_rows(ds.isel({dim: k})) for k in range(ds.sizes[dim])]
        return lambda scheme: [next(r for r in rows if _row_scheme(r) == scheme) for rows in per_value]
    if "dt" in ds["status"].dims:
        return orders_along(ds, dim).__getitem__
    judged = "accuracy" in ds

    def counts(scheme):
        status = per_scheme(ds["status"], scheme)
        others = tuple(axis for axis, name in enumerate(status.dims) if name != dim)
        _, inaccurate, failed, unjudged = (
            np.broadcast_to(mask.sum(axis=others), (ds.sizes[dim],)) for mask in verdicts(ds, scheme)
        )
        return [
            {
                "cases": status.size // ds.sizes[dim],
                "unstable": int(failed[k]),
                "inaccurate": int(inaccurate[k]) if judged else None,
                "unjudged": int(unjudged[k]),
            }
            for k in range(ds.sizes[dim])
        ]

    return counts


def _questions(ds, rates):
    """Per swept axis other than scheme and dt, per scheme: how the order and the energy
    change (dt swept) or the accuracy verdicts change (dt fixed) along it; a scheme along
    which nothing changes is left to its verdict."""
    result = []
    for dim in _other_dims(ds):
        size = ds.sizes[dim]
        labels = _label_values(ds, dim)
        per_label = [{name: column[k] for name, column in labels.items()} for k in range(size)]
        values = _value_texts(dim, labels)
        rows_of = _rows_along(ds, dim)
        for scheme in schemes_of(ds):
            rows = rows_of(scheme)
            numbers = {"values": per_label}
            if "dt" in ds["status"].dims:
                numbers["order"] = [None if r["order"] is None else r["order"][0] for r in rows]
                orders = [order_text(r) for r in rows]
                parts, serieses = [f"order {_series(orders, values)}"], [orders]
                if rates is not None:
                    along = per_scheme(rates, scheme)
                    status = per_scheme(ds["status"], scheme)
                    changes = [
                        _energy_text(along.isel({dim: k}), status.isel({dim: k}).values == OK)[0]
                        for k in range(size)
                    ]
                    if any(c is not None for c in changes):
                        numbers["energy_rate_per_s"] = changes
                        energy = ["kept" if c is None else f"{c:+.1e}" for c in changes]
                        parts.append("energy per s " + _series(energy, values))
                        serieses.append(energy)
            else:
                numbers["accurate_cases"] = [
                    r["cases"] - r["unstable"] - (r["inaccurate"] or 0) - r["unjudged"] for r in rows
                ]
                numbers["failed_cases"] = [r["unstable"] for r in rows]
                accurate = [f"{a}/{r['cases']}" for a, r in zip(numbers["accurate_cases"], rows, strict=True)]
                failed = [f"{r['unstable']}/{r['cases']}" for r in rows]
                parts = [f"accurate {_series(accurate, values)}", f"failed {_series(failed, values)}"]
                serieses = [accurate, failed]
            if all(len(set(series)) == 1 for series in serieses):
                continue  # nothing changes along the axis: the verdict line says it once
            head = f"{scheme} over {_axis_text(dim, labels, range(size))}: "
            texts = [head + "; ".join(parts)]
            if len(texts[0]) > MAX_LINE:  # a line a part, those that change along the axis
                texts = [
                    head + part for part, series in zip(parts, serieses, strict=True) if len(set(series)) > 1
                ]
            result.extend(
                Finding(kind="question", numbers=numbers, cases=({"scheme": scheme},), text=text)
                for text in texts
            )
    return result


def findings(ds, rows=None):
    """The findings of a study dataset, most important first: a list of `Finding`;
    ``rows``: its `scheme_rows`, where the caller has them already."""
    rates = energy_rates(ds)
    rows = scheme_rows(ds) if rows is None else rows
    return (
        _recommendation_findings(ds)
        + _failures(ds)
        + _coincidences(ds)
        + [_verdict(ds, row, rates) for row in rows]
        + _questions(ds, rates)
    )


# The table's fields for scripts: (JSON/CSV name, row key). Units are in the names.
_RECORD_FIELDS = (
    ("scheme", "scheme"),
    ("nominal_order", "nominal"),
    ("cases", "cases"),
    ("failed_cases", "unstable"),
    ("inaccurate_cases", "inaccurate"),
    ("unjudged_cases", "unjudged"),
    ("past_radioss_limit_cases", "radioss"),
    ("order_low", None),
    ("order_high", None),
    ("fits", "fits"),
    ("fit_tries", "tries"),
    ("error_rad", "error"),
    ("error_dt_s", "error_dt"),
    ("error_small_dt_rad", "error_small"),
    ("small_dt_s", "error_small_dt"),
    ("ns_per_body_step", "ns_per_step"),
    ("accurate_up_to_dt_w0", "accurate_hw"),
    ("first_inaccurate_dt_w0", "inaccurate_hw"),
    ("first_failed_dt_w0", "unstable_hw"),
    ("kept", "kept"),
)


def _json_value(value):
    """``value`` with every non-finite number as None (JSON has no NaN), tuples as lists and
    numpy scalars as Python's."""
    if isinstance(value, dict):
        return {str(k): _json_value(v) for k, v in value.items()}
    if isinstance(value, Sequence) and not isinstance(value, str | bytes):  # tuples, a finding's cases
        return [_json_value(v) for v in value]
    value = _plain(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def table_records(rows):
    """The per-scheme rows (`scheme_rows`) as flat records of named fields, units in the
    names; a value the row lacks or that is not finite (a failed case) is None."""
    records = []
    for row in rows:
        record = {}
        for name, key in _RECORD_FIELDS:
            if key is None:  # the fitted order's range
                order = row["order"]
                value = None if order is None else order[0 if name == "order_low" else 1]
            else:
                value = row.get(key)
            record[name] = _json_value(value)
        records.append(record)
    return records


def summary_document(ds):
    """The JSON form of `rbstudy summary` (docs/outputs.md): study, findings, recommended
    (one record per value of the other swept axes; scheme and dt None where no case there
    meets the bound) and schemes (`table_records`)."""
    recommended = []
    for (labels, _), pick in zip(_cases(ds), recommendations(ds), strict=True):
        fields = (
            dict.fromkeys(("scheme", "dt", "error", "seconds_per_case"))
            if pick is None
            else {
                "scheme": pick.scheme,
                "dt": pick.dt,
                "error": pick.error,
                "seconds_per_case": pick.seconds_per_case,
            }
        )
        recommended.append({**fields, **labels})
    rows = scheme_rows(ds)
    return _json_value(
        {
            "study": str(ds.attrs["study"]),
            "findings": [
                {field.name: getattr(finding, field.name) for field in dataclasses.fields(finding)}
                for finding in findings(ds, rows)
            ],
            "recommended": recommended,
            "schemes": table_records(rows),
        }
    )


def finding_lines(found):
    """The texts of ``found``, each wrapped at `MAX_LINE` (later lines indented), at most
    `MAX_FINDING_LINES` lines: the last says how many more the JSON form holds."""
    lines = [
        textwrap.wrap(finding.text, MAX_LINE, subsequent_indent="  ", break_on_hyphens=False)
        for finding in found
    ]
    if sum(map(len, lines)) <= MAX_FINDING_LINES:
        return [line for wrapped in lines for line in wrapped]
    shown = []
    for count, wrapped in enumerate(lines):
        if len(shown) + len(wrapped) > MAX_FINDING_LINES - 1:
            more = len(lines) - count
            return shown + [f"({more} more findings: --format json lists them all)"]
        shown += wrapped
    return shown


def _cell(value):
    """A list of a record (the invariants kept) as one CSV cell: "none" when empty, as the
    table says it (a missing number is an empty cell)."""
    return ", ".join(map(str, value)) or NONE


def markdown_summary(ds):
    """The findings as a list, then the table (every column) as Markdown, rendered from the
    table's one definition (`rbstudy.analysis.summary.format_table`)."""
    rows = scheme_rows(ds)
    return "\n".join(
        [f"## {ds.attrs['study']}", ""]
        + [f"- {finding.text}" for finding in findings(ds, rows)]
        + ["", format_table(rows, wide=True, fmt="markdown")]
    )


def csv_rows(ds):
    """The table's records with the study's name first, as rows for `csv.DictWriter`."""
    return [
        {
            "study": str(ds.attrs["study"]),
            **{name: _cell(value) if isinstance(value, list) else value for name, value in record.items()},
        }
        for record in table_records(scheme_rows(ds))
    ]
