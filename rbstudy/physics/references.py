"""References: the best available solution of each scene on an output grid, and its name.

An exact solution where one applies (`rbstudy.physics.analytic.reference_kinds`). A loaded
body no closed form covers is integrated twice, independently, each within a step budget:
by `exact_split` composed to order 8 at a fine step (the reference) and by scipy's DOP853 at
rtol = atol = 1e-13 (its cross-check); how far apart they end up is the reference's
``uncertainty``, which the archive keeps per case and the order fits respect. This module
sits above the schemes because it integrates; the closed forms of `analytic` stay
numba-free, and the exact free asymmetric body is the compiled `rbstudy.numerics.free_flow`.
"""

import math
from dataclasses import dataclass, field, replace

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.numerics.driver import HALT_FLAG, Halted
from rbstudy.numerics.free_flow import free_flow_batch
from rbstudy.numerics.loads import KIND
from rbstudy.numerics.state import OK
from rbstudy.physics import metrics
from rbstudy.physics.analytic import (
    INTEGRATED,
    axial_moment,
    parabola,
    reference_kinds,
    symmetric_top,
)
from rbstudy.physics.loads import TURNING, record_slice
from rbstudy.physics.simulate import simulate
from rbstudy.physics.time_grid import STEP_RTOL
from rbstudy.schemes import dop853

__all__ = [
    "Reference",
    "reference_solutions",
    "reference_solution",
    "COMPUTE",
    "REFERENCE_MAX_STEPS",
    "REFERENCE_STEPS_PER_RADIAN",
    "REFERENCE_SCHEME",
    "REFERENCE_COMPOSITION",
    "COMPOSED_STEP_ANGLE",
    "composed_steps",
    "moment_bound",
    "planned_steps",
    "knot_steps",
    "dop853_reference",
]

# Accepted DOP853 steps one reference may take: about a minute (65 us a step, measured). A free
# asymmetric body takes ~6.5 steps per radian of |w| T at rtol 1e-13 (measured for I = 1, 2, 3
# at |w| T = 18 to 1800), so the budget covers |w| T up to ~1.5e5 rad. A scene past it has no
# reference ("none") rather than a run that never ends; `validate` tells beforehand.
REFERENCE_MAX_STEPS = 1_000_000
# DOP853 steps per radian of |w| T, for that forecast.
REFERENCE_STEPS_PER_RADIAN = 6.5
# The composed reference: a momentum-exact, symmetric order-8 scheme whose free part is exact,
# so that only the loads are approximated. Its step turns the body by about this angle (rad),
# and by at most twice it at the fastest spin of the run. The angle balances truncation
# against the rounding of every stage (each rebuilds the free body's elliptic constants from
# the kicked spin): measured on I = (1, 2, 3) against an extended-precision solution, a
# step of 0.17 rad leaves 1e-13 rad of truncation over 10 s and one of 0.34 rad 1.4e-12,
# while steps four times finer than 0.15 rad gather 1e-11 of rounding (docs/theory.md s6).
REFERENCE_SCHEME = "exact_split"
REFERENCE_COMPOSITION = 8
COMPOSED_STEP_ANGLE = 0.15
# How many step counts from the angle's `composed_steps` tries for one that puts the knots of
# load tables on step boundaries (a knot given to three decimals finds one within 1000).
_KNOT_SEARCH = 1000
# Knots the search checks at once: arrays of at most this many by `_KNOT_SEARCH` floats (8 MB).
_KNOT_CHUNK = 1000


@dataclass(frozen=True)
class Reference:
    """A reference trajectory on T output times: quaternion (T, 4), omega_body (T, 3) rad/s,
    position and velocity (T, 3); ``name`` (one of the reference kinds of
    `rbstudy.physics.analytic`) says where it comes from. ``uncertainty``: for an integrated
    reference that a second, independent integration checked, how far that one lies from it
    per error measure (orientation rad, omega relative, nodes m; `_differences`), else
    empty."""

    name: str
    quaternion: np.ndarray
    omega_body: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    uncertainty: dict = field(default_factory=dict)


def _symmetric_tops(scenes, times):
    """The free symmetric tops, in one vectorised closed-form call."""
    quaternion, omega = symmetric_top(
        [scene.body.inertia for scene in scenes],
        [scene.quaternion for scene in scenes],
        [scene.omega_body for scene in scenes],
        times,
    )
    return [
        Reference("symmetric_top", quaternion[k], omega[k], *parabola(scene, times))
        for k, scene in enumerate(scenes)
    ]


def _free_bodies(scenes, times):
    """The free asymmetric bodies, every body and time in one compiled call (each time from
    the initial state: nothing accumulates along the run)."""
    quaternion = np.empty((len(scenes), times.size, 4))
    omega = np.empty((len(scenes), times.size, 3))
    free_flow_batch(
        np.array([scene.body.inertia for scene in scenes], dtype=float),
        np.array([scene.quaternion for scene in scenes], dtype=float),
        np.array([scene.omega_body for scene in scenes], dtype=float),
        times,
        quaternion,
        omega,
    )
    return [
        Reference("exact_asymmetric", quaternion[k], omega[k], *parabola(scene, times))
        for k, scene in enumerate(scenes)
    ]


def _axial_moments(scenes, times):
    references = []
    for scene in scenes:
        quaternion, omega = axial_moment(
            scene.body.inertia, scene.quaternion, scene.omega_body, scene.loads.moment_body, times
        )
        references.append(Reference("axial_moment", quaternion, omega, *parabola(scene, times)))
    return references


def dop853_reference(scene, times):
    """DOP853 at ``times``, or None past `REFERENCE_MAX_STEPS` steps (or when DOP853 itself
    fails): no reference rather than a hang."""
    run = dop853.integrate(
        scene.state_row(), scene.param_row(), times, max_steps=REFERENCE_MAX_STEPS, halt=HALT_FLAG
    )
    if HALT_FLAG[0]:
        raise Halted("the DOP853 references were halted")
    if not run.finished:
        return None
    return Reference("dop853", **{name: run.samples[:, place] for name, place in S.STATE_FIELDS.items()})


# The loads that may speed the body's spin up (every kind that turns it, but those that only
# take energy out).
_DRIVING = tuple(name for name in TURNING if not KIND[name].dissipates)


def moment_bound(loads):
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


def planned_steps(omega_body, inertia, loads, interval):
    """(n,) steps per output ``interval`` that turn each body by at most
    `COMPOSED_STEP_ANGLE` at the rate ``|w0| + sqrt(M / I_min)`` (M: `moment_bound`; the
    second term is the rate a moment of that size swings the body at, as a pendulum's), for
    (n, 3) angular velocities and inertias and their ``loads`` columns."""
    rate = np.linalg.norm(omega_body, axis=-1) + np.sqrt(moment_bound(loads) / np.min(inertia, axis=-1))
    return np.maximum(1, np.ceil(interval * rate / COMPOSED_STEP_ANGLE)).astype(np.int64)


def knot_steps(knots, duration, interval, least):
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


def composed_steps(scene, interval, least=None):
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
    """`REFERENCE_SCHEME` composed to order `REFERENCE_COMPOSITION` at `composed_steps` per
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
            {"composition": REFERENCE_COMPOSITION},
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


def _integrated(scenes, times):
    """Two independent integrations of each loaded scene: the exact-flow splitting composed to
    order 8 at a fine step (`_composed`), which is the reference, and DOP853, its
    cross-check; their difference is the reference's ``uncertainty``. Where knots of the load
    tables cannot be put on the composition's steps, DOP853 is the reference and nothing
    checks it; where one of the two is not had (a step budget passed, a failure) the other
    is the reference, unchecked; where neither is, the case has no reference ("none"), never
    a hang."""
    references = []
    for scene in scenes:
        composed = _composed(scene, times)
        peer = dop853_reference(scene, times)
        if composed is not None and peer is not None:
            composed = replace(composed, uncertainty=_differences(scene, composed, peer))
        best = composed or peer
        references.append(
            best or Reference("none", *(np.full((times.size, k), np.nan) for k in (4, 3, 3, 3)))
        )
    return references


# How each reference kind (`rbstudy.physics.analytic.REFERENCE_KINDS`) is computed, for a
# list of scenes at once (a test checks that every kind has its computation).
COMPUTE = {
    "symmetric_top": _symmetric_tops,
    "axial_moment": _axial_moments,
    "exact_asymmetric": _free_bodies,
    INTEGRATED: _integrated,
}


def reference_solutions(scenes, times):
    """The best available reference of each of ``scenes`` at ``times`` (T,), increasing from
    0 (the run's output times), `Reference`s.

    Scenes are grouped by kind and each kind computed in one call (the symmetric tops of a
    batch vectorised).
    """
    times = np.asarray(times, dtype=float)
    kinds = reference_kinds(
        [scene.body.inertia for scene in scenes],
        [scene.omega_body for scene in scenes],
        {name: [getattr(scene.loads, name) for scene in scenes] for name in KIND},
        [scene.loads.timed for scene in scenes],
    )
    found = {}
    for kind, compute in COMPUTE.items():
        members = [i for i, k in enumerate(kinds) if k == kind]
        if members:
            computed = compute([scenes[i] for i in members], times)
            found.update(zip(members, computed, strict=True))
    return [found[i] for i in range(len(scenes))]


def reference_solution(scene, times):
    """The best available reference for one ``scene`` (see `reference_solutions`)."""
    return reference_solutions([scene], times)[0]
