"""The study's answer in words: ranked findings read from its dataset (never from a rerun).

`findings(ds)` returns `Finding` records, most important first:

1. the recommendation: the cheapest scheme and step that meet the study's accuracy bound
   (the archive's per-case ``accuracy`` verdict: orientation error at every sample, energy and
   ``|L|`` drift), costed by the kernel time per case (`case_seconds`); one for the whole
   study, then one per distinct answer where the values of the other swept axes disagree, or
   a statement that no case meets the bound (the numbers: `rbstudy.analysis.recommend`);
   then, where cases failed, one per status: the cases, what it means and what to try
   (`rbstudy.numerics.state.STATUSES`, as the scorecard says it); where the body flips about
   its intermediate axis, the exact flip interval and which schemes lost or added flips
   (`rbstudy.analysis.flips`);
2. coincidences: schemes whose final orientation errors agree to 3 digits in every case;
3. each scheme's verdict in one line, from `rbstudy.analysis.summary.scheme_rows`, then
   where the body flips each scheme's flip-interval error, its order and its flips;
4. the study's own question, for every swept axis other than scheme and ``dt`` (a scheme
   option, a body parameter): the order and energy change per value where ``dt`` is swept,
   the accuracy verdicts per value where it is not. A scheme along which nothing changes is
   left to its verdict; a line wider than `MAX_LINE` is told a part a line.

Orders, invariants kept and the ``dt |w0|`` ranges are the summary's own: nothing here fits
or measures anything the table does not, so the words and the table cannot disagree. The
other forms of the summary (JSON, Markdown, CSV) are `rbstudy.analysis.summary_forms`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import xarray as xr

from rbstudy.analysis.finding import Finding
from rbstudy.analysis.flips import CONDITIONING_VARIABLES, FLIP_VARIABLES, flip_findings
from rbstudy.analysis.places import (
    SHOWN_VALUES,
    CaseLabels,
    Members,
    axis_text,
    label_values,
    other_dims,
    runs_text,
    significant,
    value_texts,
)
from rbstudy.analysis.recommend import (
    Candidate,
    Choice,
    Picks,
    Recommendation,
    calibrated,
    candidate,
    case_seconds,
    picks_of,
    recommendations,
    study_wide,
    swept_order,
)
from rbstudy.analysis.summary import (
    COINCIDENT_DIGITS,
    ERROR_MEASURES,
    FLOOR_WORDS,
    KEPT_TOLERANCE,
    SUMMARY_VARIABLES,
    coinciding_pairs,
    error_measure,
    floor_reason,
    order_text,
    orders_along,
    per_scheme,
    scheme_rows,
    schemes_of,
    status_counts,
    status_text,
    verdicts,
)
from rbstudy.archive.variables import BUSY_UNCERTAINTY
from rbstudy.numerics.state import INVARIANTS, OK, STATUS_NAMES

# The recommendation's numbers (`rbstudy.analysis.recommend`) are named here too: the report,
# the figures and the search's words read them with the findings.
__all__ = [
    "Finding",
    "Recommendation",
    "findings",
    "recommendations",
    "energy_rates",
    "FINDINGS_VARIABLES",
    "FINDINGS_REDUCED",
    "MAX_LINE",
    "case_seconds",
    "calibrated",
    "EDGE_SHARE",
    "study_wide",
]

# What `findings` reads: the table's per-case scalars (the calibrated step cost among them),
# the energy series whose last value says whether a scheme gains or loses energy, and the
# cost's uncertainty, within which two costs are a tie.
FINDINGS_VARIABLES = (
    *SUMMARY_VARIABLES,
    "energy_error",
    "step_seconds_uncertainty",
    *FLIP_VARIABLES,
    *CONDITIONING_VARIABLES,
)
# Of those, the time series the findings reduce along time, and how; read so
# (`rbstudy.archive.load.open_results`), a million cases' findings hold 16 MB of them, not 176 MB.
FINDINGS_REDUCED = {"momentum_error": "max", "energy_error": "last"}
# A recommended error within this share of the bound is at its edge, and said so: a step a
# little larger, or another body, may pass it (euler was recommended at 0.00995 rad against
# the default bound 0.01).
EDGE_SHARE = 0.01
# A finding's line is at most this wide where it can be (a terminal of 100 columns): a
# question whose parts do not fit together is told in a line per part.
MAX_LINE = 100
# What an older archive's recommendation adds: its costs move with its run's timer.
_UNCALIBRATED = "; costed by run_time, which moves between runs (sweep again to store calibrated step costs)"


def _choice_text(choice: Choice) -> str:
    """``rk4 at dt=0.01 s``; with candidates of equal cost ``rk4 or rkmk4, equal cost, at
    dt=0.01 s`` (another dt named with its scheme)."""
    scheme, dt, tied = choice.scheme, choice.dt, choice.tied
    if not tied:
        return f"{scheme} at dt={significant(dt)} s"
    if all(other.dt == dt for other in tied):
        return (
            _alternatives([scheme, *(other.scheme for other in tied)])
            + f", equal cost, at dt={significant(dt)} s"
        )
    return (
        _alternatives(
            [f"{one.scheme} at dt={significant(one.dt)} s" for one in (Candidate(scheme, dt), *tied)]
        )
        + ", equal cost"
    )


def _alternatives(names: list[str]) -> str:
    """``a or b``, ``a, b or c``."""
    return ", ".join(names[:-1]) + f" or {names[-1]}"


def _at_edge(error: float, bound: float | None) -> bool:
    return bool(bound is not None and math.isfinite(error) and error >= (1.0 - EDGE_SHARE) * bound)


def _error_text(error: float, bound: float, tail: str | None = None) -> str:
    """``error 2.8e-07 rad``, or at the bound's edge (`EDGE_SHARE`) ``error 0.00995 rad:
    within 1% of the bound 0.01``; with a ``tail`` (``", every case)"``), the bound follows
    the error (``error 2.8e-07 rad (bound 0.01, every case)``)."""
    if _at_edge(error, bound):
        return (
            f"error {significant(error)} rad: within {EDGE_SHARE:.0%} of the bound {significant(bound)}"
            + (f" ({tail.removeprefix(', ')}" if tail and tail != ")" else "")
        )
    return f"error {significant(error)} rad" + (
        f" (bound {significant(bound)}{tail}" if tail is not None else ""
    )


def _capped(ds: xr.Dataset, dt: float) -> bool:
    """Whether ``dt`` is the largest step of a swept ``dt``: the grid, not the bound, may
    have stopped the answer there."""
    return bool("dt" in ds["status"].dims and ds.sizes["dt"] > 1 and dt == float(ds["dt"].max()))


def _capped_text(dt: float, short: bool = False) -> str:
    """What a recommendation at the largest swept ``dt`` says; ``short`` for a per-value line,
    under the study-wide one that says it whole."""
    if short:
        return f"capped by the grid (dt={significant(dt)} s, the largest swept)"
    return (
        f"capped by the grid: dt={significant(dt)} s is the largest swept, a larger one may also meet the "
        "bound (widen sweep.dt, or sweep --find-step)"
    )


def _recommendation_numbers(ds: xr.Dataset, choice: Choice, bound: float) -> dict[str, Any]:
    """The numbers of a recommendation finding (units in the names)."""
    return {
        "dt_s": choice.dt,
        "seconds_per_case": choice.seconds,
        "error_rad": choice.error,
        "accuracy_bound": bound,
        "equal_cost": [{"scheme": other.scheme, "dt_s": other.dt} for other in choice.tied],
        "capped_by_grid": _capped(ds, choice.dt),
        "at_bound_edge": _at_edge(choice.error, bound),
        "cost_model": "calibrated step_seconds" if calibrated(ds) else "run_time",
    }


def _recommendation_findings(ds: xr.Dataset) -> list[Finding]:
    """The recommendation: the study-wide answer where one scheme and step meet the bound
    everywhere, then one per distinct answer where the values of the other axes disagree (or
    where none meets the bound at some), or why there is none."""
    bound: Any = ds.attrs.get("accuracy_bound")  # a float wherever the archive has verdicts
    if "accuracy" not in ds:
        return [
            Finding(
                kind="no_recommendation",
                numbers={},
                cases=(),
                text="no recommendation: the archive has no accuracy verdict",
            )
        ]
    picks = picks_of(ds)
    if not picks.met.any():
        return [
            Finding(
                kind="no_recommendation",
                numbers={"accuracy_bound": bound},
                cases=(),
                text=f"no scheme and step meet the accuracy bound {significant(bound)} in any case",
            )
        ]
    uniform = study_wide(ds)
    result = [] if uniform is None else [_study_wide_finding(ds, uniform, bound)]
    answers = len(np.unique(np.packbits(picks.tied[picks.met], axis=1), axis=0))  # of equal cost
    if uniform is None or answers > 1 or not picks.met.all():
        result += _per_value_findings(
            ds, picks, bound, short_cap=uniform is not None and _capped(ds, uniform.dt)
        )
    return result


def _study_wide_finding(ds: xr.Dataset, uniform: Choice, bound: float) -> Finding:
    """The recommendation for the whole study (`study_wide`); an older archive's costs move
    with its run's timer: said where the answer is."""
    everywhere = ", every case" if other_dims(ds) else ""
    text = (
        f"recommended: {_choice_text(uniform)}, "
        f"{significant(uniform.seconds, 2)} s a case, {_error_text(uniform.error, bound, f'{everywhere})')}"
    )
    if _capped(ds, uniform.dt):
        text += "; " + _capped_text(uniform.dt)
    return Finding(
        kind="recommendation",
        cases=({"scheme": uniform.scheme, "dt": uniform.dt},),
        numbers=_recommendation_numbers(ds, uniform, bound),
        text=text + ("" if calibrated(ds) else _UNCALIBRATED) + _busy_text(ds, uniform),
    )


# How an answer says that its costs were measured on a busy machine (`_busy_text`): the page
# of the conformance card says it once for every case (`rbstudy.analysis.card_page`).
BUSY_CLAUSE = "; their costs were measured while other programs kept the machine busy"


def _busy_text(ds: xr.Dataset, choice: Choice) -> str:
    """What the answer adds where the costs of its schemes were measured while other
    programs kept the machine busy (`BUSY_UNCERTAINTY`): why so many are of equal cost."""
    if "step_seconds_uncertainty" not in ds:
        return ""
    uncertainty = ds["step_seconds_uncertainty"]
    if "scheme" in uncertainty.dims:
        uncertainty = uncertainty.sel(scheme=[choice.scheme, *(tied.scheme for tied in choice.tied)])
    if not bool((uncertainty >= BUSY_UNCERTAINTY).any()):
        return ""
    return (
        f"{BUSY_CLAUSE}, uncertain to {BUSY_UNCERTAINTY:.0%} (sweep again on a quiet machine to tell "
        "them apart)"
    )


def _per_value_findings(ds: xr.Dataset, picks: Picks, bound: float, short_cap: bool) -> list[Finding]:
    """A finding per distinct answer over the values of the other axes, in the order of its
    first value, each naming where it holds; ``short_cap``: the study-wide finding has said
    what a grid-capped step means. Grouped by answer (and its candidates of equal cost) as
    arrays; a mapping per case only for the finding's own cases (a million cases'
    `Recommendation` objects and labels took far more memory than the arrays)."""
    labels = CaseLabels(ds)
    # grouped by the candidates of equal cost, not by the one that represents them at each
    # value: "euler or leapfrog" at one ratio and "leapfrog or euler" at the next are one
    # answer, told once
    tied = picks.tied & picks.met[:, None]
    keys = np.column_stack([picks.met, np.packbits(tied, axis=1)])
    _, first_of, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    result = []
    for first in np.sort(first_of):
        members = np.flatnonzero(group == group[first])
        where = labels.where(members)
        if not picks.met[first]:
            result.append(
                Finding(
                    kind="no_recommendation",
                    numbers={"accuracy_bound": bound},
                    cases=Members(labels, members),
                    text=f"no scheme and step meet the bound {significant(bound)} at {where}",
                )
            )
            continue
        answer = _group_answer(ds, picks, members, np.flatnonzero(tied[first]))
        text = (
            f"cheapest at {where}: {_choice_text(answer)}, {significant(answer.seconds, 2)} s a case, "
            + _error_text(answer.error, bound)
        )
        if _capped(ds, answer.dt):
            text += "; " + _capped_text(answer.dt, short=short_cap)
        result.append(
            Finding(
                kind="recommendation",
                cases=Members(labels, members, {"scheme": answer.scheme, "dt": answer.dt}),
                numbers=_recommendation_numbers(ds, answer, bound),
                text=text,
            )
        )
    return result


def _group_answer(ds: xr.Dataset, picks: Picks, members: np.ndarray, candidates: np.ndarray) -> Choice:
    """The answer of the values ``members`` (indices), whose tied ``candidates`` (C-order
    positions) are the same: the candidate with the smallest worst error over them
    represents it, with their largest cost and its largest error."""
    worst = np.nan_to_num(picks.errors[np.ix_(members, candidates)], nan=np.inf).max(axis=0)
    chosen = candidates[int(np.argmin(worst))]
    order = swept_order(ds)
    answer = candidate(ds, chosen, order)
    return Choice(
        scheme=answer.scheme,
        dt=answer.dt,
        seconds=float(picks.seconds[members].max()),
        error=float(picks.errors[members, chosen].max()),
        tied=tuple(candidate(ds, k, order) for k in candidates if k != chosen),
    )


def _failures(ds: xr.Dataset) -> list[Finding]:
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


def _coincidences(ds: xr.Dataset) -> list[Finding]:
    error = error_measure(ds, "orientation")
    if error is None:  # nothing to compare
        return []
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


def energy_rates(ds: xr.Dataset) -> xr.DataArray | None:
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


def _energy_text(rates: xr.DataArray, stable: np.ndarray) -> tuple[float | None, str | None]:
    """(the largest rate, ``loses energy, up to 0.0012/s``) over the ``stable`` cases, or
    (None, None) when their energy ends within `KEPT_TOLERANCE` of its start (kept)."""
    values = rates.values[stable]
    # a case that ends within round-off of its start energy neither gains nor loses
    values = values[np.abs(values) * rates.attrs["duration"] >= KEPT_TOLERANCE]
    if not values.size:
        return None, None
    largest = float(values[np.argmax(np.abs(values))])
    trend = "gains" if np.all(values > 0) else "loses" if np.all(values < 0) else "gains or loses"
    return largest, f"{trend} energy, up to {significant(abs(largest), 2)}/s"


def _row_scheme(row: dict[str, Any]) -> str:
    return row["scheme"].split(",")[0]


def _verdict(ds: xr.Dataset, row: dict[str, Any], rates: xr.DataArray | None) -> Finding:
    name, numbers = row["scheme"], dict[str, Any]()
    floor = ERROR_MEASURES["orientation"].floor
    largest = row.get("error")
    reason = floor_reason(row)
    at_float64 = row.get("float64_floor")
    if at_float64 is not None:
        numbers["float64_floor_rad"], numbers["float64_floor_dt"], _ = at_float64
    if reason == "round-off" and at_float64 is not None and at_float64[2]:  # every error within it
        parts = [f"at the float64 floor ({significant(at_float64[0], 2)} rad)"]
        if largest is not None:
            numbers["error_rad"] = largest
    elif reason is not None:  # no order through errors at the floor (exact_split's "0.60")
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
    if at_float64 is not None and reason is None:  # the finest errors, left out of the fit
        parts.append(
            f"at the float64 floor ({significant(at_float64[0], 2)} rad) from dt = {at_float64[1]:g} s"
        )
    if row["nominal"] is not None:
        numbers["nominal_order"] = row["nominal"]
    if np.isfinite(row["accurate_hw"]):
        numbers["accurate_up_to_dt_w0"] = row["accurate_hw"]
        parts.append(f"accurate to dt|w0| {significant(row['accurate_hw'])}")
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
        start = f" from dt|w0| {significant(row['unstable_hw'])}" if np.isfinite(row["unstable_hw"]) else ""
        numbers["first_failed_dt_w0"] = row["unstable_hw"]
        parts.append(f"fails {row['unstable']}/{row['cases']}{start}")
    if row["radioss"]:
        numbers["past_radioss_limit"] = row["radioss"]
        parts.append(f"past Radioss limit {row['radioss']}/{row['cases']}")
    numbers["cases"] = row["cases"]
    return Finding(
        kind="verdict", text=f"{name}: " + "; ".join(parts), numbers=numbers, cases=({"scheme": scheme},)
    )


def _series(texts: list[str], values: list[str]) -> str:
    """``texts``, one per value of an axis (``values``, its `value_texts`), none lost: each
    in turn (``4.00, 4.00, 3.99``, in the order of the values the line names) where they are
    few or all differ, else each run of equal neighbours with the values it holds for, ``4.00
    at 0.0001 to 0.1, 3.99 at 0.316, none at 1 to 10000``."""
    runs: list[tuple[str, list[int]]] = []
    for k, text in enumerate(texts):
        if runs and runs[-1][0] == text:
            runs[-1][1].append(k)
        else:
            runs.append((text, [k]))
    if len(texts) <= SHOWN_VALUES or 2 * len(runs) > len(texts):
        return ", ".join(texts)
    return ", ".join(f"{text} at {runs_text(values, held)}" for text, held in runs)


def _rows_along(ds: xr.Dataset, dim: str) -> Callable[[str], list[dict[str, Any]]]:
    """``scheme -> [row of scheme_rows(ds.isel({dim: k})) for each k]``: the first row of
    each scheme at each value along ``dim``. Where no swept option sets the order, only
    what `_questions` reads is computed, along ``dim`` at once: where ``dt`` is swept, the
    order fields (`orders_along`), else the case counts (cases, unstable, inaccurate,
    unjudged). A table per value was slow for a thousand values, and took most of the
    default study's findings for four."""
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


def _questions(ds: xr.Dataset, rates: xr.DataArray | None) -> list[Finding]:
    """Per swept axis other than scheme and dt, per scheme: how the order and the energy
    change (dt swept) or the accuracy verdicts change (dt fixed) along it; a scheme along
    which nothing changes is left to its verdict."""
    result: list[Finding] = []
    for dim in other_dims(ds):
        size = ds.sizes[dim]
        labels = label_values(ds, dim)
        per_label = [{name: column[k] for name, column in labels.items()} for k in range(size)]
        values = value_texts(dim, labels)
        rows_of = _rows_along(ds, dim)
        for scheme in schemes_of(ds):
            rows = rows_of(scheme)
            numbers: dict[str, Any] = {"values": per_label}
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
            head = f"{scheme} over {axis_text(dim, labels, range(size))}: "
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


def findings(ds: xr.Dataset, rows: list[dict[str, Any]] | None = None) -> list[Finding]:
    """The findings of a study dataset, most important first: a list of `Finding`;
    ``rows``: its `scheme_rows`, where the caller has them already."""
    rates = energy_rates(ds)
    rows = scheme_rows(ds) if rows is None else rows
    flips, scheme_flips = flip_findings(ds)
    return (
        _recommendation_findings(ds)
        + _failures(ds)
        + flips
        + _coincidences(ds)
        + [_verdict(ds, row, rates) for row in rows]
        + scheme_flips
        + _questions(ds, rates)
    )
