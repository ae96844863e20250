"""References: the best available solution of each scene on an output grid, and its name.

An exact solution where one applies (`rbstudy.physics.analytic.reference_kinds`), scipy's
DOP853 at rtol = atol = 1e-13 otherwise, within a step budget. This module sits above the
schemes because the fallback integrates; the closed forms of `analytic` stay numba-free, and
the exact free asymmetric body is the compiled `rbstudy.numerics.free_flow`.
"""

from dataclasses import dataclass

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.numerics.driver import HALT_FLAG, Halted
from rbstudy.numerics.free_flow import free_flow_batch
from rbstudy.physics.analytic import (
    axial_moment,
    parabola,
    reference_kinds,
    symmetric_top,
)
from rbstudy.schemes import dop853

__all__ = ["Reference", "reference_solutions", "reference_solution", "COMPUTE",
           "REFERENCE_MAX_STEPS", "REFERENCE_STEPS_PER_RADIAN"]

# Accepted DOP853 steps one reference may take: about a minute (65 us a step, measured). A free
# asymmetric body takes ~6.5 steps per radian of |w| T at rtol 1e-13 (measured for I = 1, 2, 3
# at |w| T = 18 to 1800), so the budget covers |w| T up to ~1.5e5 rad. A scene past it has no
# reference ("none") rather than a run that never ends; `validate` tells beforehand.
REFERENCE_MAX_STEPS = 1_000_000
# DOP853 steps per radian of |w| T, for that forecast.
REFERENCE_STEPS_PER_RADIAN = 6.5


@dataclass(frozen=True)
class Reference:
    """A reference trajectory on T output times: quaternion (T, 4), omega_body (T, 3) rad/s,
    position and velocity (T, 3); ``name`` (one of the reference kinds of
    `rbstudy.physics.analytic`) says where it comes from."""

    name: str
    quaternion: np.ndarray
    omega_body: np.ndarray
    position: np.ndarray
    velocity: np.ndarray


def _symmetric_tops(scenes, times):
    """The free symmetric tops, in one vectorised closed-form call."""
    quaternion, omega = symmetric_top(
        [scene.body.inertia for scene in scenes], [scene.quaternion for scene in scenes],
        [scene.omega_body for scene in scenes], times)
    return [Reference("symmetric_top", quaternion[k], omega[k], *parabola(scene, times))
            for k, scene in enumerate(scenes)]


def _free_bodies(scenes, times):
    """The free asymmetric bodies, every body and time in one compiled call (each time from
    the initial state: nothing accumulates along the run)."""
    quaternion = np.empty((len(scenes), times.size, 4))
    omega = np.empty((len(scenes), times.size, 3))
    free_flow_batch(np.array([scene.body.inertia for scene in scenes], dtype=float),
                    np.array([scene.quaternion for scene in scenes], dtype=float),
                    np.array([scene.omega_body for scene in scenes], dtype=float),
                    times, quaternion, omega)
    return [Reference("exact_asymmetric", quaternion[k], omega[k], *parabola(scene, times))
            for k, scene in enumerate(scenes)]


def _axial_moments(scenes, times):
    references = []
    for scene in scenes:
        quaternion, omega = axial_moment(scene.body.inertia, scene.quaternion,
                                         scene.omega_body, scene.loads.moment_body, times)
        references.append(Reference("axial_moment", quaternion, omega, *parabola(scene, times)))
    return references


def _dop853(scenes, times):
    """DOP853 sampled at ``times``, case by case, each within `REFERENCE_MAX_STEPS` steps:
    past them (or when DOP853 itself fails) the case has no reference ("none"), never a
    hang."""
    references = []
    for scene in scenes:
        run = dop853.integrate(scene.state_row(), scene.param_row(), times,
                               max_steps=REFERENCE_MAX_STEPS, halt=HALT_FLAG)
        if HALT_FLAG[0]:
            raise Halted("the DOP853 references were halted")
        samples = run.samples if run.finished else np.full_like(run.samples, np.nan)
        references.append(Reference("dop853" if run.finished else "none",
                                    **{name: samples[:, place]
                                       for name, place in S.STATE_FIELDS.items()}))
    return references


# How each reference kind (`rbstudy.physics.analytic.REFERENCE_KINDS`) is computed, for a
# list of scenes at once (a test checks that every kind has its computation).
COMPUTE = {"symmetric_top": _symmetric_tops, "axial_moment": _axial_moments, "dop853": _dop853,
           "exact_asymmetric": _free_bodies}


def reference_solutions(scenes, times):
    """The best available reference of each of ``scenes`` at ``times`` (T,), increasing from
    0 (the run's output times), `Reference`s.

    Scenes are grouped by kind and each kind computed in one call (the symmetric tops of a
    batch vectorised).
    """
    times = np.asarray(times, dtype=float)
    kinds = reference_kinds(
        [scene.body.inertia for scene in scenes], [scene.omega_body for scene in scenes],
        {name: [getattr(scene.loads, name) for scene in scenes]
         for name in ("force_body", "moment_space", "moment_body", "lever")},
        [scene.loads.timed for scene in scenes])
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
