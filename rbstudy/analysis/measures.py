"""The error measures of an archive and their asymptotic ranges (`ERROR_MEASURES`), shared by
the per-scheme table, the figures, the findings and the report: each case's measure
(`error_measure`), its reference's uncertainty and its round-off floor, the order fitted
over the steps where the errors are neither at the floor nor too large to be asymptotic
(`fitted_order`), and why no order can be fitted where none is (`at_floor`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import xarray as xr

from rbstudy.physics.metrics import MIN_ASYMPTOTIC_POINTS, OrderFit, asymptotic_order

__all__ = [
    "ERROR_MEASURES",
    "ErrorMeasure",
    "FLOOR_FACTOR",
    "KEPT_TOLERANCE",
    "ROUND_OFF_ULPS",
    "UNCERTAINTY_FACTOR",
    "at_floor",
    "error_measure",
    "fitted_order",
    "round_off_of",
    "uncertainty_of",
]


class ErrorMeasure(NamedTuple):
    """An error measure of the archive, as the table, the figures and the report show it.

    label, units : its words and units. floor, ceiling : its asymptotic range: below the floor
    an error is round-off, above the ceiling it is not asymptotic (or the run failed).
    variable : the archive's variable. uncertainty : the variable of the uncertainty of its
    reference, or None (a closed form, or a measure not against a reference). turns : whether
    its round-off grows with the angle the body turns (`round_off_of`). floor_kind : what sets
    its floor, in the words the figures say it with (``"round-off"``, or ``"sampling"`` for a
    time read between samples). conditioned : its floor is also `FLOOR_FACTOR` times the
    archive's ``float64_floor`` (an orientation angle at the last time: one ulp of the initial
    state carried by the exact motion).
    """

    label: str
    units: str
    floor: float
    ceiling: float
    variable: str
    uncertainty: str | None = None
    turns: bool = False
    floor_kind: str = "round-off"
    conditioned: bool = False


# The floor is a few hundred ulps of the quantity (rounding summed over 1e3-1e4 steps, relative
# to 1); energy and |L| are relative to their exact start values and sit lower.
# `metrics.asymptotic_order` also cuts the range where the local slopes stop agreeing, so a
# floor set a little low costs nothing. A measure taken against an integrated reference also
# has a floor of `UNCERTAINTY_FACTOR` times that reference's uncertainty, case by case.
ERROR_MEASURES = {
    "orientation": ErrorMeasure(
        label="final orientation error",
        units="rad",
        floor=1e-13,
        ceiling=1e-1,
        variable="final_orientation_error",
        uncertainty="reference_uncertainty",
        turns=True,
        conditioned=True,
    ),
    "omega": ErrorMeasure(
        label="max relative angular velocity error",
        units="1",
        floor=1e-13,
        ceiling=1e-1,
        variable="omega_error",
        uncertainty="reference_omega_uncertainty",
        turns=True,
    ),
    "nodes": ErrorMeasure(
        label="max node position error",
        units="m",
        floor=1e-13,
        ceiling=1e-1,
        variable="node_error",
        uncertainty="reference_node_uncertainty",
    ),
    "energy": ErrorMeasure(
        label="max relative energy error", units="1", floor=1e-15, ceiling=1e-1, variable="max_energy_error"
    ),
    "momentum_magnitude": ErrorMeasure(
        label="max relative error of |L| (magnitude)",
        units="1",
        floor=1e-15,
        ceiling=1e-1,
        variable="max_momentum_magnitude_error",
    ),
    # the vector L = R m at the samples carries the rounding of R and m over thousands of
    # steps: 1e-14 to 1e-13 for the schemes that keep it
    "momentum_vector": ErrorMeasure(
        label="max relative |L - L0| (vector)",
        units="1",
        floor=1e-12,
        ceiling=1e-1,
        variable="momentum_error",
    ),
    "precession": ErrorMeasure(
        label="|precession frequency error|",
        units="rad/s",
        floor=1e-13,
        ceiling=1e-1,
        variable="precession_frequency_error",
    ),
    # zero crossings of samples placed by linear interpolation: ~1e-6 s at best, the floor of
    # the sampling, far above the float64 round-off of the motion
    "flip": ErrorMeasure(
        label="|flip interval error|",
        units="s",
        floor=1e-5,
        ceiling=1.0,
        variable="flip_interval_error",
        floor_kind="sampling",
    ),
}
# An error within this factor of the float64 floor (`float64_floor`: one ulp of the initial
# state, carried to the last time by the exact motion) is at the floor: rounding the initial
# state alone moves the result that far, and each step rounds it again.
FLOOR_FACTOR = 3.0
# An error within this factor of its reference's uncertainty says as much about the reference
# as about the scheme: no order is fitted through it.
UNCERTAINTY_FACTOR = 10.0
# A measure that turns with the body rounds about an ulp a step and an ulp of the largest
# angle the run's motion sweeps: exact_split, exact on a free body, ends the Abaqus top
# 9.8e-13 rad off after 6,400 steps (0.7 ulp a step) and stiff_inertia's disk of I3/I1 = 1e4
# (its precession sweeps 6.3e4 rad in 1 s) 1.4e-11 rad off at every dt, at most 1.3 ulps of
# steps and angle together; twice that is round-off (`round_off_of`). Ten times it took MuJoCo's
# and rbstudy's rk4 for round-off on Drake's floating body, whose errors at 3,200 steps
# (2.4e-12 rad) still fall by 16 a halving: a floor must sit under the errors a scheme makes.
ROUND_OFF_ULPS = 2.0
# A run one of whose steps turned the body by more than this (rad) has gone wild: a loaded
# body's leapfrog on the heavy top reached 1e123 rad a step, finite, and its bookkeeping
# watches no invariant under a load. Its error has no round-off to speak of: its floor stays
# the measure's constant one (it raised it to 1 rad, which the figure called round-off).
WILD_STEP = 1.0
# An invariant counts as kept when its largest relative drift over every step of every
# stable case stays below this: round-off over 1e4-1e5 steps, far below any truncation error.
KEPT_TOLERANCE = 1e-10


def error_measure(ds: xr.Dataset, key: str) -> xr.DataArray | None:
    """|error measure| ``key`` of every case (time and nodes reduced by max), or None."""
    name = ERROR_MEASURES[key].variable
    if name not in ds:
        return None
    value = ds[name]
    reduce = [d for d in value.dims if d in ("time", "node")]
    return abs(value.max(reduce, skipna=False) if reduce else value)


def uncertainty_of(ds: xr.Dataset, key: str, like: xr.DataArray) -> xr.DataArray | None:
    """The uncertainty of the reference of measure ``key`` per case, broadcast like the
    measure ``like``; None where the archive has none (closed-form references)."""
    name = ERROR_MEASURES[key].uncertainty
    return ds[name].broadcast_like(like) if name is not None and name in ds else None


def round_off_of(ds: xr.Dataset, key: str, like: xr.DataArray) -> xr.DataArray:
    """The round-off floor of measure ``key`` per case, broadcast like the measure ``like``:
    its constant ``floor`` (relative to 1), raised for a measure that ``turns`` with the body to
    `ROUND_OFF_ULPS` float64 ulps of its steps (``n_steps``) plus the largest angle the run's
    motion sweeps: ``|w| T`` (``max_step_angle`` times ``n_steps``) times the inertia's
    largest over its smallest moment, as fast as ``|L| / I_min``, the precession of L seen
    from the body, can outrun ``|w|``. A relative measure that does not turn (units 1: the
    energy, ``|L|`` and ``L`` drifts) is raised to `ROUND_OFF_ULPS` ulps of its steps alone:
    the schemes that keep them end 1e-15 to 1e-13 off after hundreds of steps, no order to
    fit. A failed case (no finite angle), or one whose step turned the body by more than
    `WILD_STEP`, keeps the constant floor: its error is NaN or meaningless. A
    ``conditioned`` measure's floor is at least `FLOOR_FACTOR` times the archive's
    ``float64_floor`` where it has one (a closed-form reference)."""
    spec = ERROR_MEASURES[key]
    floor = like.copy(data=np.full(like.shape, spec.floor))
    if spec.conditioned and "float64_floor" in ds.variables:
        conditioning = (FLOOR_FACTOR * ds["float64_floor"]).broadcast_like(like).transpose(*like.dims)
        floor = np.fmax(floor, conditioning)
    if not spec.turns:
        if spec.units != "1" or "n_steps" not in ds.variables:
            return floor
        steps = (ROUND_OFF_ULPS * np.finfo(float).eps * ds["n_steps"]).broadcast_like(like)
        return np.fmax(floor, steps.transpose(*like.dims))
    if not {"max_step_angle", "n_steps", "inertia"} <= set(ds.variables):
        return floor
    inertia = ds["inertia"]
    steps = ds["n_steps"]
    swept = steps + ds["max_step_angle"] * steps * inertia.max("axis") / inertia.min("axis")
    scaled = (ROUND_OFF_ULPS * np.finfo(float).eps * swept).where(ds["max_step_angle"] <= WILD_STEP)
    return np.fmax(floor, scaled.broadcast_like(like).transpose(*like.dims))


def fitted_order(
    dts: npt.ArrayLike,
    errors: npt.ArrayLike,
    key: str,
    uncertainty: npt.ArrayLike | None = None,
    round_off: npt.ArrayLike | None = None,
) -> OrderFit:
    """Observed order of measure ``key`` over its asymptotic range, an
    `rbstudy.physics.metrics.OrderFit` (order, used mask, finest pair's slope). A point at the
    floor is not fitted: at or below its ``round_off`` (per point, `round_off_of`; None: the
    measure's constant floor), or below `UNCERTAINTY_FACTOR` times its reference's
    ``uncertainty`` (per point; NaN or None: none known)."""
    spec = ERROR_MEASURES[key]
    return asymptotic_order(dts, errors, _floor(spec.floor, uncertainty, round_off), spec.ceiling)


def _floor(constant: float, uncertainty: npt.ArrayLike | None, round_off: npt.ArrayLike | None) -> Any:
    """The larger of the round-off floor (``round_off`` per point, else ``constant``) and
    `UNCERTAINTY_FACTOR` times the reference's ``uncertainty`` (NaN: none known)."""
    floor = constant if round_off is None else np.asarray(round_off, dtype=float)
    if uncertainty is not None:
        floor = np.fmax(floor, UNCERTAINTY_FACTOR * np.asarray(uncertainty, dtype=float))
    return floor


def at_floor(
    errors: npt.ArrayLike, round_off: npt.ArrayLike, uncertainty: npt.ArrayLike | None = None
) -> str | None:
    """Why no order can be fitted through ``errors`` over the steps: ``"round-off"`` when too
    few finite errors lie above their ``round_off`` (per point) for a fit (fewer than
    `MIN_ASYMPTOTIC_POINTS` where that many are finite, else none), ``"reference"`` when too
    few lie above `UNCERTAINTY_FACTOR` times the reference's ``uncertainty`` as well; None
    when enough do (or no error is finite: the cases failed)."""
    values = np.asarray(errors, dtype=float)
    finite = np.isfinite(values)

    def too_few(above):
        shown = finite & above
        enough = finite.sum() >= MIN_ASYMPTOTIC_POINTS
        return shown.sum() < MIN_ASYMPTOTIC_POINTS and (enough or not shown.any())

    if not finite.any():
        return None
    if too_few(values > round_off):
        return "round-off"
    return "reference" if too_few(values > _floor(0.0, uncertainty, round_off)) else None
