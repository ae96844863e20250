"""The study's recommendation in numbers: the cheapest scheme and step that meet its accuracy
bound, per value of the other swept axes (`recommendations`) and for the whole study
(`study_wide`), read from its dataset (never from a rerun).

A case meets the bound where the archive's ``accuracy`` verdict says so and it finished; its
cost is its kernel time (`case_seconds`); costs within their calibration's uncertainty are a
tie (`_choose`), which the smaller error represents. The words of the answer are the
findings' (`rbstudy.analysis.findings`).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any

import numpy as np
import xarray as xr

from rbstudy.analysis.places import SWEPT_BY_SUMMARY, cases_of, other_dims
from rbstudy.analysis.summary import error_measure, schemes_of
from rbstudy.archive.variables import ACCURATE
from rbstudy.numerics.state import OK

__all__ = [
    "Candidate",
    "Choice",
    "Picks",
    "Recommendation",
    "calibrated",
    "case_seconds",
    "candidate",
    "picks_of",
    "recommendations",
    "study_wide",
    "swept_order",
]


class Candidate(typing.NamedTuple):
    """A scheme and a step (s) the recommendation may name."""

    scheme: str
    dt: float


class Choice(typing.NamedTuple):
    """An answer: its ``scheme`` and ``dt`` (s), its kernel ``seconds`` per case, its final
    orientation ``error`` (rad) and the other candidates of equal cost, ``tied``
    (`Candidate`: `_choose`), of which it has the smallest error. The study-wide answer
    (`study_wide`) gives its mean seconds and worst error over the other axes' values, an
    answer for several values (the findings') its largest of each over them."""

    scheme: str
    dt: float
    seconds: float
    error: float
    tied: tuple[Candidate, ...]


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
    axes: dict[str, Any]
    tied: tuple[Candidate, ...] = ()


def calibrated(ds: xr.Dataset) -> bool:
    """Whether ``ds`` costs its cases by the calibrated model (its ``step_seconds``: archives
    before it have none)."""
    return "step_seconds" in ds


def case_seconds(ds: xr.Dataset) -> xr.DataArray:
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


def _choose(seconds, uncertainty, error, scheme):
    """Per row of candidates (n, m): the cheapest, and those whose cost is within the
    calibration's uncertainty of it (their ranges overlap), a tie; the one of them with the
    smallest ``error`` (then the earliest) represents them. ``seconds`` is inf where a
    candidate does not meet the bound; ``scheme`` (m,) each candidate's scheme. The
    uncertainty is of a scheme's cost per step, which all its candidates share: they compare
    exactly among themselves, so a scheme's dearer candidates are never in a tie (a wide
    uncertainty, a calibration on a busy machine's, made a step and its half one answer).
    Returns (pick (n,), tied (n, m))."""
    rows = np.arange(seconds.shape[0])
    cheapest = np.argmin(seconds, axis=1)
    least, spread = seconds[rows, cheapest][:, None], uncertainty[rows, cheapest][:, None]
    own_least = np.empty_like(seconds)
    for each in np.unique(scheme):
        own = scheme == each
        own_least[:, own] = seconds[:, own].min(axis=1, keepdims=True)
    with np.errstate(invalid="ignore"):
        overlap = seconds * (1.0 - uncertainty) <= least * (1.0 + spread)
        tied = np.isfinite(seconds) & overlap & (seconds == own_least)
    ranked = np.where(tied, np.nan_to_num(error, nan=np.inf), np.inf)
    pick = np.where(tied.any(axis=1), np.argmin(ranked, axis=1), cheapest)
    return pick, tied


def _candidate_schemes(ds: xr.Dataset, order: list[str]) -> np.ndarray:
    """The scheme's position of each (scheme, dt) candidate in C order along ``order``
    (`swept_order`): (m,), 0 where the scheme is not swept."""
    shape = [ds.sizes[d] for d in order]
    if "scheme" not in order:
        return np.zeros(math.prod(shape), dtype=int)
    return np.unravel_index(np.arange(math.prod(shape)), shape)[order.index("scheme")]


def swept_order(ds: xr.Dataset) -> list[str]:
    """The axes of `SWEPT_BY_SUMMARY` that ``ds`` sweeps, in that order: the candidates'
    C order."""
    return [d for d in SWEPT_BY_SUMMARY if d in ds["status"].dims]


class Picks(typing.NamedTuple):
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


def picks_of(ds: xr.Dataset) -> Picks:
    """The `Picks` of ``ds``, every value of the other axes at once. Cheapest: the least
    `case_seconds`, costs within their uncertainty a tie that the smaller error represents
    (`_choose`); then the earlier scheme, then the earlier dt (archive order: the smaller,
    as dt is stored ascending since rbstudy 0.4)."""
    order = swept_order(ds)
    dims = [*other_dims(ds), *order]

    def flat(value):  # (n, cases of one value of the other axes), in ``order``'s C order
        values = value.broadcast_like(ds["status"]).transpose(*dims).values
        return values.reshape(-1, math.prod(ds.sizes[d] for d in order))

    good = flat((ds["accuracy"] == ACCURATE) & (ds["status"] == OK))
    seconds = np.where(good, flat(case_seconds(ds)), np.inf)
    error = error_measure(ds, "orientation")
    errors = flat(error) if error is not None else np.full(seconds.shape, math.nan)
    cheapest, tied = _choose(seconds, flat(_cost_uncertainty(ds)), errors, _candidate_schemes(ds, order))
    shape = [ds.sizes[d] for d in order]
    position = dict(zip(order, np.unravel_index(cheapest, shape), strict=True)) if order else {}
    everywhere = np.arange(len(cheapest))
    zeros = np.zeros_like(cheapest)
    return Picks(
        met=good.any(axis=1),
        scheme=position.get("scheme", zeros),
        dt=position.get("dt", zeros),
        error=errors[everywhere, cheapest],
        seconds=seconds[everywhere, cheapest],
        tied=tied,
        errors=errors,
    )


def candidate(ds: xr.Dataset, flat: int | np.integer, order: list[str]) -> Candidate:
    """The `Candidate` at C-order position ``flat`` along ``order`` (`swept_order`)."""
    shape = [ds.sizes[d] for d in order]
    at = dict(zip(order, np.unravel_index(flat, shape), strict=True)) if order else {}
    return Candidate(
        scheme=str(schemes_of(ds)[at.get("scheme", 0)]),
        dt=float(np.atleast_1d(ds["dt"].values)[at.get("dt", 0)]),
    )


def recommendations(ds: xr.Dataset) -> list[Recommendation | None]:
    """The cheapest accurate (scheme, dt) for every value of the other swept axes: a list of
    `Recommendation`, with None where no case of that value meets the bound (`picks_of`)."""
    if "accuracy" not in ds:
        return []
    picks = picks_of(ds)
    schemes = schemes_of(ds)
    dts = np.atleast_1d(ds["dt"].values)
    order = swept_order(ds)
    found: list[Recommendation | None] = []
    for k, (labels, _) in enumerate(cases_of(ds)):
        if not picks.met[k]:
            found.append(None)
            continue
        chosen = Candidate(scheme=str(schemes[picks.scheme[k]]), dt=float(dts[picks.dt[k]]))
        found.append(
            Recommendation(
                scheme=chosen.scheme,
                dt=chosen.dt,
                error=float(picks.error[k]),
                seconds_per_case=float(picks.seconds[k]),
                axes=labels,
                tied=tuple(
                    other
                    for other in (candidate(ds, j, order) for j in np.flatnonzero(picks.tied[k]))
                    if other != chosen
                ),
            )
        )
    return found


def study_wide(ds: xr.Dataset) -> Choice | None:
    """The cheapest (scheme, dt) that meets the bound in every case of the other axes, by
    total kernel time, costs within their uncertainty a tie that the smaller worst error
    represents: a `Choice` (its mean seconds, its worst error), or None."""
    order = swept_order(ds)
    others = other_dims(ds)
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
    pick, tied = _choose(seconds, spread, worst, _candidate_schemes(ds, order))
    flat = int(pick[0])
    chosen = candidate(ds, flat, order)
    return Choice(
        scheme=chosen.scheme,
        dt=chosen.dt,
        seconds=float(seconds[0, flat]),
        error=float(worst[0, flat]),
        tied=tuple(candidate(ds, k, order) for k in np.flatnonzero(tied[0]) if k != flat),
    )
