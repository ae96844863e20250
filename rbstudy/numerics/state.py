"""Memory layout of the per-body rows: the only place that knows indices.

A batch of B bodies is C-ordered float64 arrays with one row per body: ``state`` (B, N_STATE),
``params`` (B, W >= N_PARAM), scheme ``options`` (B, N_OPTION) in, and per-body ``results``
(B, N_RESULT) out. A body's row is contiguous, so each thread of the batch driver streams
through its own body's data while it integrates all steps of that body.

State row (SI units):
    POSITION  3  centre-of-mass position in space (m)
    QUATERNION 4 orientation of the principal body frame, scalar-last (x, y, z, w); maps body
                 to space
    VELOCITY  3  centre-of-mass velocity in space (m/s)
    OMEGA     3  angular velocity in the principal body frame (rad/s)

Parameter row:
    MASS 1, INERTIA 3 (principal, kg m^2), then a slot per kind of load in the order of the
    catalogue `rbstudy.numerics.loads` (which lays them out; tabulated kinds first):
    FORCE_SPACE 3 (N), FORCE_BODY 3 (N, body axes),
    MOMENT_SPACE 3 (N m), MOMENT_BODY 3 (N m, body axes), GRAVITY 3 (m/s^2, space),
    LEVER 9 (N m): space-fixed forces ``F_i`` at body-fixed points ``d_i`` (principal axes,
    from the centre of mass), as the rows ``k_b = sum_i d_i[b] F_i`` of ``sum_i d_i F_i^T``;
    their moment ``sum_i (R d_i) x F_i = sum_b (R e_b) x k_b`` in space turns with the body
    (`rbstudy.numerics.space_loads.lever_moment`). Their sum ``F`` is part of FORCE_SPACE.
    Then the kinds that are never tabulated: the damping coefficients 3 (N m s, principal
    axes; `rbstudy.numerics.dynamics.spin_damping`).
    KNOTS 1: the number K of knots of the loads tabulated in time (0: all loads constant).
    The row then goes on past N_PARAM with the K knot times (s, increasing) and, at each knot,
    a record of the tabulated loads laid out as the constant ones from FIRST_SLOT
    (`LOAD_RECORD` values, principal body axes). Between knots the record is interpolated
    linearly, before the first and after the last it is held; it adds to the constant loads
    (`rbstudy.numerics.space_loads.tabulated_moment`). Rows of one batch may hold different K:
    the batch is as wide as its widest row (`row_width`).

Results row: `RESULT_FIELDS`, by name; kernels index it with ``Result.<name>``. Numba-free:
the layers above read this layout and the status codes without compiling anything.
"""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:  # the module imports no numpy: its arrays come from the caller
    import numpy as np

from rbstudy.numerics.loads import END_SLOT, KIND, RECORD_WIDTH

__all__ = [
    "POSITION",
    "QUATERNION",
    "VELOCITY",
    "OMEGA",
    "N_STATE",
    "STATE_FIELDS",
    "MASS",
    "INERTIA",
    "FORCE_SPACE",
    "FORCE_BODY",
    "MOMENT_SPACE",
    "MOMENT_BODY",
    "GRAVITY",
    "LEVER",
    "KNOTS",
    "N_PARAM",
    "LOAD_RECORD",
    "row_width",
    "N_OPTION",
    "RESULT_FIELDS",
    "RADIOSS_STEP_ANGLE",
    "Result",
    "N_RESULT",
    "Status",
    "STATUSES",
    "OK",
    "UNSTABLE",
    "NOT_CONVERGED",
    "STATUS_NAMES",
    "INVARIANTS",
]

POSITION = 0
QUATERNION = 3
VELOCITY = 7
OMEGA = 10
N_STATE = 13
# The state row's fields by the names the rest of rbstudy gives them (a scene's initial
# values, a simulation's samples, a reference), as slices of the row.
STATE_FIELDS = {
    "position": slice(POSITION, POSITION + 3),
    "quaternion": slice(QUATERNION, QUATERNION + 4),
    "velocity": slice(VELOCITY, VELOCITY + 3),
    "omega_body": slice(OMEGA, OMEGA + 3),
}

MASS = 0
INERTIA = 1
# The load slots, laid out by the catalogue of load kinds (`rbstudy.numerics.loads`).
FORCE_SPACE = KIND["force_space"].offset
FORCE_BODY = KIND["force_body"].offset
MOMENT_SPACE = KIND["moment_space"].offset
MOMENT_BODY = KIND["moment_body"].offset
GRAVITY = KIND["gravity"].offset
LEVER = KIND["lever"].offset
KNOTS = END_SLOT
N_PARAM = KNOTS + 1
# Values of one knot's record of tabulated loads: the tabulated kinds' slots, as in the row
# from FIRST_SLOT on.
LOAD_RECORD = RECORD_WIDTH


def row_width(knots: int | np.ndarray) -> int | np.ndarray:
    """Width of a parameter row whose loads are tabulated at ``knots`` times.

    Parameters
    ----------
    knots : int or ndarray of ints, shape (B,)
        Knots of each row (0: constant loads).

    Returns
    -------
    int or ndarray of ints, shape (B,)
        ``W = N_PARAM + knots (1 + LOAD_RECORD)``.
    """
    return N_PARAM + knots * (1 + LOAD_RECORD)


# Scheme options (e.g. HHT alpha, splitting axis order) travel per body in a row of this width,
# so that a batch may mix option values and a sweep over an option needs no recompilation.
N_OPTION = 5

# What the driver reports per body, declared once: (name, storage type). The names are those
# of the archive's variables; the storage type is numpy's. A kernel writes column
# ``Result.<name>``; `rbstudy.numerics.driver.BatchOutput` hands them on by name.
RESULT_FIELDS = (
    ("status", "i1"),  # OK / UNSTABLE / NOT_CONVERGED
    ("failure_time", "f8"),  # s; NaN for a body that finished
    ("n_steps", "i8"),  # steps taken
    ("iterations", "i8"),  # Newton iterations (an adaptive scheme: rhs evaluations)
    ("max_energy_error", "f8"),  # largest relative rotational-energy drift over the steps
    ("max_momentum_magnitude_error", "f8"),  # largest relative drift of |L| over the steps
    ("max_step_angle", "f8"),  # rad; largest dt |w| over the accepted states (t = 0
    # included; an adaptive scheme: each step's own dt and
    # the |w| it ends with)
    ("radioss_dt_limit", "i1"),  # 1 where (dt |w|)^2 > 1 at some step (OpenRadioss aborts)
)
# OpenRadioss aborts a rigid body as unstable when (dt |w|)^2 > 1: past this step angle (rad)
# a case is flagged `radioss_dt_limit`, and runs on (the study shows what happens past it).
RADIOSS_STEP_ANGLE = 1.0
# built from the table above, so that the two cannot differ; mypy reads only literal members
Result = enum.IntEnum("Result", [(name, k) for k, (name, _) in enumerate(RESULT_FIELDS)])  # type: ignore[misc]
N_RESULT = len(RESULT_FIELDS)


class Status(NamedTuple):
    """What a body's status code says: its ``name`` (the archive's flag meaning), what
    happened (``message``) and what to try (``fix``), as the command line, the report and
    the scorecard print them."""

    name: str
    message: str
    fix: str


# Status codes of a body: the code is the index. Archives store the code (append only:
# archived codes must keep their meaning); the messages are part of the archive's
# description of `status` (`rbstudy.archive.variables`).
STATUSES = (
    Status("ok", "finished", ""),
    Status(
        "unstable",
        "blew up (a non-finite state, or an energy or |L| drift past 50% for a moment-free body)",
        "take a smaller dt (the stability map shows the dt |w0| where "
        "it starts), or a scheme that keeps the energy (`rbstudy schemes` says which)",
    ),
    Status(
        "not_converged",
        "the implicit solver failed",
        "take a smaller dt: the Newton iteration then starts nearer its answer (dop853, "
        "whose step budget ran out: a shorter duration)",
    ),
)
STATUS_NAMES = tuple(status.name for status in STATUSES)
OK, UNSTABLE, NOT_CONVERGED = range(len(STATUSES))

# The invariants a scheme may claim to keep to round-off for the moment-free body, and how
# they read: the energy, the magnitude |L| of the angular momentum, the space vector L itself
# (which keeps |L| too). Here, numba-free, for the summary table as well as the registry.
INVARIANTS = {"energy": "energy", "momentum_magnitude": "|L|", "momentum_vector": "L"}
