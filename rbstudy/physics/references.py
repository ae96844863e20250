"""References: the best available solution of each scene on an output grid, and its name.

A sweep takes them as columns (`References`, from the rows of its scene table:
`table_references`), with no object per case; `Reference` is one case's view, which tests
and analysis take (`reference_solutions` of `Scene`s).

An exact solution where one applies (`rbstudy.physics.analytic.reference_kinds`). A loaded
body no closed form covers is integrated twice, independently, each within a step budget:
by `exact_split` composed to order 8 with compensated sums at a fine step (the reference)
and by scipy's DOP853 at rtol = atol = 1e-13 (its cross-check); how far apart they end up
is the reference's ``uncertainty``, which the archive keeps per case and the order fits
respect. This module sits above the schemes because it integrates; the closed forms of
`analytic` stay numba-free, and the exact free asymmetric body is the compiled
`rbstudy.numerics.free_flow`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from rbstudy.numerics import state as S
from rbstudy.numerics.driver import HALT_FLAG, Halted
from rbstudy.numerics.free_flow import free_flow_batch
from rbstudy.numerics.heavy_top import lagrange_top_batch
from rbstudy.numerics.loads import KIND
from rbstudy.numerics.state import OK
from rbstudy.physics import metrics
from rbstudy.physics.analytic import (
    INTEGRATED,
    REFERENCE_KINDS,
    axial_moment,
    parabola,
    reference_kinds,
    symmetric_top,
    symmetrised,
    symmetry_axes,
)
from rbstudy.physics.loads import TURNING, record_slice
from rbstudy.physics.quaternions import quat_mul
from rbstudy.physics.reference_data import NONE_CODE, Reference, References
from rbstudy.physics.scenes import Scene, SceneTable
from rbstudy.physics.simulate import simulate
from rbstudy.physics.time_grid import STEP_RTOL
from rbstudy.schemes import dop853

__all__ = [
    "Reference",
    "References",
    "table_references",
    "reference_solutions",
    "reference_solution",
    "COMPUTE",
    "REFERENCE_MAX_STEPS",
    "REFERENCE_STEPS_PER_RADIAN",
    "REFERENCE_SCHEME",
    "REFERENCE_OPTIONS",
    "COMPOSED_STEP_ANGLE",
    "composed_steps",
    "moment_bound",
    "planned_steps",
    "load_spin",
    "knot_steps",
    "dop853_reference",
    "table_floors",
    "ULP",
]

# Accepted DOP853 steps one reference may take: a few minutes of one core at the cost of a step
# as measured (`rbstudy.pipeline.calibration.reference_cost`). A free
# asymmetric body takes ~6.5 steps per radian of |w| T at rtol 1e-13 (measured for I = 1, 2, 3
# at |w| T = 18 to 1800), so the budget covers |w| T up to ~1.5e5 rad. A scene past it has no
# reference ("none") rather than a run that never ends; `validate` tells beforehand.
REFERENCE_MAX_STEPS = 1_000_000
# DOP853 steps per radian of |w| T, for that forecast.
REFERENCE_STEPS_PER_RADIAN = 6.5
# The composed reference: a momentum-exact, symmetric order-8 scheme whose free part is exact,
# so that only the loads are approximated, its increments added with compensated summation
# (`rbstudy.numerics.free_increment`): plain sums gathered an ulp of the state a stage, 6.0e-12
# rad over 100 s under a space moment of 0.15 N m on I = (1, 2, 3), compensated ones 1.2e-13
# (against an extended-precision solution, docs/theory.md s6). Its step turns the
# body by about this angle (rad), and by at most twice it at the fastest spin of the run: a
# step of 0.17 rad leaves 1e-13 rad of truncation over 10 s and one of 0.34 rad 1.4e-12.
REFERENCE_SCHEME = "exact_split"
REFERENCE_OPTIONS = {"composition": 8, "compensated": 1}
COMPOSED_STEP_ANGLE = 0.15
# How many step counts from the angle's `composed_steps` tries for one that puts the knots of
# load tables on step boundaries (a knot given to three decimals finds one within 1000).
_KNOT_SEARCH = 1000
# Knots the search checks at once: arrays of at most this many by `_KNOT_SEARCH` floats (8 MB).
_KNOT_CHUNK = 1000


class _Group(NamedTuple):
    """m scenes as the closed forms take them: principal ``inertia`` (m, 3), symmetrised as
    each `Body` does, ``quaternion`` (m, 4), ``omega_body``, ``position``, ``velocity`` (m,
    3), ``mass`` (m,), ``loads``: each kind of `rbstudy.numerics.loads` -> (m, width); and
    ``scene(k)``, the k-th as a `Scene` (for the integrations, one case at a time)."""

    inertia: np.ndarray
    quaternion: np.ndarray
    omega_body: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    mass: np.ndarray
    loads: dict
    scene: object


def _table_group(table, rows):
    """The `_Group` of rows ``rows`` (m,) of ``table``, taken from its columns."""
    return _Group(
        inertia=symmetrised(table.inertia[rows]),
        quaternion=table.quaternion[rows],
        omega_body=table.omega_body[rows],
        position=table.position[rows],
        velocity=table.velocity[rows],
        mass=table.mass[rows],
        loads={name: table.loads[name][rows] for name in KIND},
        scene=lambda k: table.scene(rows[k]),
    )


def _scene_group(scenes):
    """The `_Group` of a list of `Scene`s."""
    return _Group(
        inertia=np.array([scene.body.inertia for scene in scenes], dtype=float).reshape(-1, 3),
        **{
            name: np.array([getattr(scene, name) for scene in scenes], dtype=float).reshape(-1, width)
            for name, width in (("quaternion", 4), ("omega_body", 3), ("position", 3), ("velocity", 3))
        },
        mass=np.array([scene.body.mass for scene in scenes], dtype=float),
        loads={
            name: np.array([getattr(scene.loads, name) for scene in scenes], dtype=float) for name in KIND
        },
        scene=lambda k: scenes[k],
    )


def _centres(group, members, times, found):
    """The centres of mass of ``members`` on their parabolas, into ``found``."""
    loads = group.loads
    found.position[members], found.velocity[members] = parabola(
        group.position[members],
        group.velocity[members],
        loads["force_space"][members] / group.mass[members, None] + loads["gravity"][members],
        times,
    )


def _symmetric_tops(group, members, times, found):
    """The free symmetric tops, in one vectorised closed-form call."""
    found.quaternion[members], found.omega_body[members] = symmetric_top(
        group.inertia[members], group.quaternion[members], group.omega_body[members], times
    )
    _centres(group, members, times, found)


def _free_bodies(group, members, times, found):
    """The free asymmetric bodies, every body and time in one compiled call (each time from
    the initial state: nothing accumulates along the run)."""
    quaternion = np.empty((members.size, times.size, 4))
    omega = np.empty((members.size, times.size, 3))
    free_flow_batch(
        np.ascontiguousarray(group.inertia[members]),
        np.ascontiguousarray(group.quaternion[members]),
        np.ascontiguousarray(group.omega_body[members]),
        times,
        quaternion,
        omega,
    )
    found.quaternion[members], found.omega_body[members] = quaternion, omega
    _centres(group, members, times, found)


def _lagrange_tops(group, members, times, found):
    """The Lagrange tops, every top and time in one compiled call; a top the closed form
    refuses (`rbstudy.numerics.heavy_top.REFUSALS`) is integrated instead."""
    taken = _lagrange_closed(group, members, times, found)
    _integrated(group, members[~taken], times, found)


def _lagrange_closed(group, members, times, found):
    """The Lagrange tops that the closed form takes, into ``found``: which it took, (m,)."""
    inertia = np.ascontiguousarray(group.inertia[members])
    axes = symmetry_axes(inertia)
    levers = group.loads["lever"][members].reshape(-1, 3, 3)
    quaternion = np.empty((members.size, times.size, 4))
    omega = np.empty((members.size, times.size, 3))
    refused = np.zeros(members.size, dtype=np.int64)
    lagrange_top_batch(
        inertia,
        axes,
        np.ascontiguousarray(group.quaternion[members]),
        np.ascontiguousarray(group.omega_body[members]),
        np.ascontiguousarray(levers[np.arange(members.size), axes]),
        times,
        quaternion,
        omega,
        refused,
    )
    taken = refused == 0
    found.quaternion[members[taken]], found.omega_body[members[taken]] = quaternion[taken], omega[taken]
    _centres(group, members[taken], times, found)
    return taken


def _axial_moments(group, members, times, found):
    for k in members:
        found.quaternion[k], found.omega_body[k] = axial_moment(
            group.inertia[k], group.quaternion[k], group.omega_body[k], group.loads["moment_body"][k], times
        )
    _centres(group, members, times, found)


def dop853_reference(scene: Scene, times: np.ndarray) -> Reference | None:
    """DOP853 at ``times``, or None past `REFERENCE_MAX_STEPS` steps (or when DOP853 itself
    fails): no reference rather than a hang."""
    run = dop853.integrate(
        scene.state_row(), scene.param_row(), times, max_steps=REFERENCE_MAX_STEPS, halt=HALT_FLAG
    )
    if HALT_FLAG[0]:
        raise Halted("the DOP853 references were halted")
    if not run.finished:
        return None
    fields: dict[str, Any] = {name: run.samples[:, place] for name, place in S.STATE_FIELDS.items()}
    return Reference("dop853", **fields)


# The loads that may speed the body's spin up (every kind that turns it, but those that only
# take energy out).
_DRIVING = tuple(name for name in TURNING if not KIND[name].dissipates)


def moment_bound(loads: Mapping[str, Any]) -> np.ndarray | float:
    """An upper bound (N m) of the moment's magnitude at any time, (...,): every constant
    and tabulated moment that may drive the body, and the lever of off-centre forces, added
    up. ``loads`` maps the
    `rbstudy.physics.scenes.Loads` fields to arrays with the same leading dims (...) (a
    `SceneTable`'s columns, or one scene's fields with a leading axis of one)."""
    records = np.asarray(loads["tabulated"])  # (..., K, LOAD_RECORD)
    bound = 0.0
    for name in _DRIVING:
        tabulated = (
            np.abs(records[..., record_slice(name)]).sum(axis=-1).max(axis=-1, initial=0.0)
            if KIND[name].tabulated
            else 0.0
        )
        bound = bound + np.abs(loads[name]).sum(axis=-1) + tabulated
    return bound


def planned_steps(
    omega_body: np.ndarray, inertia: np.ndarray, loads: Mapping[str, Any], interval: float
) -> np.ndarray:
    """(n,) steps per output ``interval`` that turn each body by at most
    `COMPOSED_STEP_ANGLE` at the rate ``|w0| + sqrt(M / I_min)`` (M: `moment_bound`; the
    second term is the rate a moment of that size swings the body at, as a pendulum's), for
    (n, 3) angular velocities and inertias and their ``loads`` columns."""
    rate = np.linalg.norm(omega_body, axis=-1) + np.sqrt(moment_bound(loads) / np.min(inertia, axis=-1))
    return np.maximum(1, np.ceil(interval * rate / COMPOSED_STEP_ANGLE)).astype(np.int64)


def load_spin(inertia: np.ndarray, loads: Mapping[str, Any], duration: float) -> np.ndarray:
    """(n,) the most a load can add to each body's spin (rad/s) by ``duration`` (s): ``M T /
    I_min`` (M: `moment_bound`), for (n, 3) inertias and their ``loads`` columns. A moment M
    changes the energy E at ``w . M <= |w| M`` and ``|w| <= sqrt(2 E / I_min)``, so
    ``sqrt(2 E / I_min)``, and with it the spin's bound, grows by at most ``M / I_min`` a
    second. Reached when the load keeps pumping the spin (a moment fixed in space, about the
    axis of least inertia); a moment that turns with a tumbling body reaches far less."""
    return moment_bound(loads) * duration / np.min(inertia, axis=-1)


def knot_steps(knots: npt.ArrayLike, duration: float, interval: float, least: int) -> int | None:
    """The first step count per output ``interval`` from ``least`` that puts every knot
    (K,) inside (0, ``duration``) on a step boundary, or None within `_KNOT_SEARCH` counts
    (a load's kink inside a step costs the composition its order; DOP853 restarts there
    instead). The knots are tried `_KNOT_CHUNK` at a time against the counts that still fit,
    so that a table of 1e5 knots needs megabytes, not the gigabytes of all knots by all
    counts at once (the counts found are the same)."""
    knots = np.asarray(knots)
    knots = knots[(knots > 0.0) & (knots < duration)]
    counts = np.arange(least, least + _KNOT_SEARCH)
    fits = np.ones(counts.size, dtype=bool)
    for start in range(0, knots.size, _KNOT_CHUNK):
        steps = knots[start : start + _KNOT_CHUNK, None] * (counts[fits] / interval)  # (knots, counts)
        fits[fits] = np.all(np.abs(steps - np.round(steps)) <= STEP_RTOL * np.maximum(steps, 1.0), axis=0)
        if not fits.any():
            return None
    return int(counts[fits.argmax()])


def composed_steps(scene: Scene, interval: float, least: int | None = None) -> int | None:
    """The steps per output ``interval`` of ``scene``'s composed reference: at least
    ``least`` (default `planned_steps`), with every knot on a step boundary (`knot_steps`);
    None when no such count is found."""
    if least is None:
        columns = {name: np.asarray(value)[None] for name, value in vars(scene.loads).items()}
        least = int(
            planned_steps(np.array([scene.omega_body]), np.array([scene.body.inertia]), columns, interval)[0]
        )
    return knot_steps(scene.loads.knots, scene.duration, interval, least)


def _composed(scene, times):
    """`REFERENCE_SCHEME` with `REFERENCE_OPTIONS` (composed to order 8) at `composed_steps` per
    output interval of ``times`` (evenly spaced from 0), or None when it cannot be had: the
    knots of the loads do not fit its steps, it fails, or it needs more than
    `REFERENCE_MAX_STEPS` steps. A body that speeds up past the step's angle (a load pumps
    it up) is run again at a step fitted to the fastest spin it reached."""
    if times.size < 2 or not np.allclose(np.diff(times), times[1] - times[0]):
        return None
    interval = float(times[1] - times[0])
    scene = replace(scene, duration=float(times[-1]))
    count = composed_steps(scene, interval)
    for _ in range(2):
        if count is None or count * (times.size - 1) > REFERENCE_MAX_STEPS:
            return None
        run = simulate(
            [scene],
            REFERENCE_SCHEME,
            interval / count,
            interval,
            REFERENCE_OPTIONS,
            threads=1,
        )
        if run.results["status"][0] != OK:
            return None
        angle = float(run.results["max_step_angle"][0])
        if angle <= 2.0 * COMPOSED_STEP_ANGLE:
            break
        count = composed_steps(scene, interval, math.ceil(count * angle / COMPOSED_STEP_ANGLE))
    return Reference(INTEGRATED, **{name: run.field(name)[0] for name in S.STATE_FIELDS})


def _largest(values):
    """The largest finite value (NaN if none: a relative error against a body at rest)."""
    values = np.asarray(values)[np.isfinite(values)]
    return float(values.max()) if values.size else math.nan


def _differences(scene, reference, check):
    """How far ``check`` lies from ``reference`` in each error measure the references serve,
    taken as the measures are: the orientation angle at the last output time (rad; the
    fitted measure is the final orientation error, and DOP853's samples between its steps
    are interpolated, ~1e-12 off), the largest relative angular velocity difference and the
    largest node distance (m, 0 without nodes) over the output times."""
    positions = [
        metrics.node_positions(r.quaternion, r.position, np.asarray(scene.nodes)) for r in (check, reference)
    ]
    with np.errstate(invalid="ignore", divide="ignore"):
        return {
            "orientation": float(metrics.orientation_error(check.quaternion[-1], reference.quaternion[-1])),
            "omega": _largest(metrics.omega_error(check.omega_body, reference.omega_body)),
            "nodes": _largest(metrics.node_error(*positions)) if len(scene.nodes) else 0.0,
        }


def _integrated(group, members, times, found):
    """Two independent integrations of each loaded scene: the exact-flow splitting composed to
    order 8 at a fine step (`_composed`), which is the reference, and DOP853, its
    cross-check; their difference is the reference's ``uncertainty``. Where knots of the load
    tables cannot be put on the composition's steps, DOP853 is the reference and nothing
    checks it; where one of the two is not had (a step budget passed, a failure) the other
    is the reference, unchecked; where neither is, the case has no reference ("none"), never
    a hang. One scene at a time: each integration costs far more than its `Scene`."""
    for k in members:
        scene = group.scene(k)
        composed = _composed(scene, times)
        peer = dop853_reference(scene, times)
        if composed is not None and peer is not None:
            composed = replace(composed, uncertainty=_differences(scene, composed, peer))
        best = composed or peer
        if best is None:
            found.code[k] = NONE_CODE  # its NaNs stay
        else:
            found.put(k, best)


# How each reference kind (`rbstudy.physics.analytic.REFERENCE_KINDS`) is computed, for a
# list of scenes at once (a test checks that every kind has its computation).
COMPUTE = {
    "symmetric_top": _symmetric_tops,
    "axial_moment": _axial_moments,
    "exact_asymmetric": _free_bodies,
    "lagrange_top": _lagrange_tops,
    INTEGRATED: _integrated,
}


# The closed forms as `_floors` evaluates them: never integrating (a Lagrange top the closed
# form refuses keeps NaN).
_CLOSED = {
    "symmetric_top": _symmetric_tops,
    "axial_moment": _axial_moments,
    "exact_asymmetric": _free_bodies,
    "lagrange_top": _lagrange_closed,
}
# The relative size of the perturbations of `_floors`: one ulp.
ULP = float(np.finfo(float).eps)


def _perturbed(group, members, kind):
    """``members`` of ``group``, each perturbed by one ulp of its initial state in every way
    `_floors` tries: the angular velocity scaled by ``1 + ULP``, and (where the closed form
    allows it, all but the axial moment) each of its components moved by ``ULP |w0|``; the
    orientation turned by ``ULP`` about each body axis. A `_Group` of p m scenes, perturbation
    by perturbation, and p."""
    omega = group.omega_body[members]
    quaternion = group.quaternion[members]
    omegas = [omega * (1.0 + ULP)]
    if kind != "axial_moment":
        size = np.linalg.norm(omega, axis=-1, keepdims=True)
        omegas += [omega + ULP * size * np.eye(3)[k] for k in range(3)]
    turns = [quat_mul(quaternion, np.r_[0.5 * ULP * np.eye(3)[k], 1.0]) for k in range(3)]
    count = len(omegas) + len(turns)
    index = np.tile(members, count)
    return (
        group._replace(
            inertia=group.inertia[index],
            quaternion=np.concatenate([quaternion] * len(omegas) + turns),
            omega_body=np.concatenate(omegas + [omega] * len(turns)),
            position=group.position[index],
            velocity=group.velocity[index],
            mass=group.mass[index],
            loads={name: np.asarray(column)[index] for name, column in group.loads.items()},
        ),
        count,
    )


def _floors(group, members, kind, times, found):
    """The float64 floor of the closed-form references ``members`` of ``kind``, into
    ``found.floor``: the largest orientation angle at the last time ``times[-1]`` between the
    reference and the same closed form from initial data perturbed by one ulp (`_perturbed`).
    No scheme can be asked to do better: rounding its initial state to float64 costs as much,
    and every step rounds it again. A top the closed form refuses keeps NaN."""
    if times[-1] <= 0.0:
        return
    perturbed, count = _perturbed(group, members, kind)
    trial = References.empty(count * members.size, 2)
    taken = _CLOSED[kind](perturbed, np.arange(count * members.size), np.array([0.0, times[-1]]), trial)
    angles = metrics.orientation_error(
        trial.quaternion[:, -1].reshape(count, members.size, 4), found.quaternion[members, -1]
    )
    if taken is not None:  # the refused ones' quaternions were left NaN
        angles = np.where(taken.reshape(count, members.size), angles, np.nan)
    closed = found.code[members] == REFERENCE_KINDS.index(kind)
    found.floor[members] = np.where(closed, angles.max(axis=0), np.nan)


def _references(group, kinds, times):
    """The `References` of a `_Group` whose scenes have the reference ``kinds`` (m,), with
    the float64 floors of the closed forms."""
    times = np.asarray(times, dtype=float)
    found = References.empty(len(kinds), times.size)
    for kind, compute in COMPUTE.items():
        members = np.flatnonzero(kinds == kind)
        if members.size:
            found.code[members] = REFERENCE_KINDS.index(kind)
            compute(group, members, times, found)
            if kind in _CLOSED:
                _floors(group, members, kind, times, found)
    return found


def table_floors(table: SceneTable, rows: np.ndarray, duration: float) -> np.ndarray:
    """(m,) the float64 floor (rad, `_floors`) at ``duration`` of the scenes ``rows`` (m,) of
    ``table`` whose reference is a closed form, NaN for the others: the closed forms alone are
    evaluated (at 0 and ``duration``), nothing is integrated."""
    group = _table_group(table, rows)
    kinds = table.reference_kinds[rows]
    times = np.array([0.0, float(duration)])
    found = References.empty(len(kinds), times.size)
    for kind, closed in _CLOSED.items():
        members = np.flatnonzero(kinds == kind)
        if members.size:
            found.code[members] = REFERENCE_KINDS.index(kind)
            taken = closed(group, members, times, found)
            if taken is not None:  # a refused top: integrated in a sweep, no floor here
                found.code[members[~taken]] = REFERENCE_KINDS.index(INTEGRATED)
            _floors(group, members, kind, times, found)
    return found.floor


def table_references(table: SceneTable, rows: np.ndarray, times: np.ndarray) -> References:
    """The best available reference of the scenes ``rows`` (m,) of ``table`` at ``times``
    (T,), increasing from 0 (the run's output times), as columns.

    Scenes are grouped by kind and each kind computed in one call (the closed forms
    vectorised over their scenes), from the table's columns: no `Scene` is built but for
    the scenes whose reference is integrated.
    """
    return _references(_table_group(table, rows), table.reference_kinds[rows], times)


def reference_solutions(scenes: Sequence[Scene], times: np.ndarray) -> list[Reference]:
    """The best available reference of each of ``scenes`` at ``times`` (T,), `Reference`s
    (the same numbers as `table_references` gives a table of them)."""
    group = _scene_group(scenes)
    kinds = reference_kinds(
        group.inertia, group.omega_body, group.loads, [scene.loads.timed for scene in scenes]
    )
    found = _references(group, kinds, times)
    return [found[k] for k in range(len(scenes))]


def reference_solution(scene: Scene, times: np.ndarray) -> Reference:
    """The best available reference for one ``scene`` (see `reference_solutions`)."""
    return reference_solutions([scene], times)[0]
