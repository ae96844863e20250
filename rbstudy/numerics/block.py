"""The block path of the driver: `BLOCK` bodies stepped together, one component per array row,
so that LLVM runs each of a step's loops over bodies several bodies to an instruction.

How a scheme plugs in
---------------------
A scheme of fixed steps that carries nothing between them may give, beside its single-body
kernels (`rbstudy.numerics.driver`), a block step

    block_step(block, opt, h)

with ``block`` the block's rows, one flat array (N_ROWS * BLOCK,): row ``STATE + k`` holds
component k of every lane's state (updated in place), row ``PARAM + k`` parameter k, rows
``TEMP..`` scratch (N_TEMP of them); ``opt`` (N_OPTION,) the option row that every body of the
block shares (a block holds only bodies of one option row); ``h`` the step. A step that can
fail on a body (Newton that does not converge) writes each lane's status and Newton iterations
of the step into rows `VERDICT` and `ITERATIONS` (which hold OK and 0 when a step starts), and
may leave alone the lanes whose row `LIVE` is 0 (bodies that have failed, lanes past the
batch). It is a few loops over the block's lanes, each short enough for LLVM to vectorise (one
loop for a whole step was not: measured, see docs/performance.md), reading and writing a
lane's entries with `at`, `column3`, `column4`, `set_column3`, `set_column4`. One flat array
of rows of a width known when compiling lets LLVM see that no two rows overlap: with 2-D
arrays of a width known only at run time it needed a check of every pair of rows before the
loop, and gave up. It must give each body the bits of the scheme's ``step_inplace`` exactly:
the same formulas in the same order, the sine and cosine of `rbstudy.numerics.lanes_math` on
both paths, no fast-math (`rbstudy.numerics.jit`).

`rbstudy.numerics.block_run` runs the blocks: which bodies go in them, and their bookkeeping.

"""

import math

from rbstudy.numerics import state as S
from rbstudy.numerics.dynamics import force_from, moment_from
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes_math import REDUCED, sin_cos_reduced
from rbstudy.numerics.rotation import norm, quat_exp_of, quat_mul, quat_normalize
from rbstudy.numerics.state import NOT_CONVERGED, OK

__all__ = [
    "BLOCK",
    "STATE",
    "PARAM",
    "TEMP",
    "N_TEMP",
    "SIN_COS_ROWS",
    "TURN_ROWS",
    "CARRIED",
    "WORK",
    "VERDICT",
    "ITERATIONS",
    "LIVE",
    "N_ROWS",
    "at",
    "column3",
    "column4",
    "set_column3",
    "set_column4",
    "quat_exp_columns",
    "sin_cos_columns",
    "start_newton",
    "end_newton",
]

# Bodies stepped together. 8 fill one AVX-512 register of doubles, but LLVM here picks 4-wide
# (AVX2) registers and each loop over lanes has its set-up, which a block of 8 pays for on
# every loop (it ran at half the speed of a block of 16); 64 leaves the loop set-up nothing
# and still fits L1 (13 + N_PARAM + N_TEMP rows of 512 bytes).
BLOCK = 64
# The fewest bodies worth a block: a block steps all its lanes, filled or not, in about the time
# the single-body loop takes for a quarter of them (leapfrog, one core), so fewer run there.
FEWEST = BLOCK // 4
# Scratch rows of a block step: rk4's last stage and its running sum, each laid out as a state.
N_TEMP = 2 * S.N_STATE
# The rows the helpers below take from their first: `sin_cos_columns` an angle, then its sine and
# cosine; `turn_columns` a rotation vector, then its quaternion.
SIN_COS_ROWS = 3
TURN_ROWS = 3 + 4
# The floats of a body's work that a block step carries from one step to the next (rows
# `WORK..`), as the scheme's ``init`` leaves them: no_squish's conjugate momentum (4), hht's
# accelerations (6).
CARRIED = 6
# Where the rows of the states, the parameters and the scratch start; then each lane's status
# and Newton iterations of the step just taken, and 1.0 for the lanes still booked.
STATE = 0
PARAM = STATE + S.N_STATE
TEMP = PARAM + S.N_PARAM
WORK = TEMP + N_TEMP
VERDICT = WORK + CARRIED
ITERATIONS = VERDICT + 1
LIVE = ITERATIONS + 1
N_ROWS = LIVE + 1


@jit
def at(a, i, lane):
    """Row ``i`` of lane ``lane`` of a block's rows ``a``.

    Parameters
    ----------
    a : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    i : int
        The row.
    lane : int
        The lane, 0 <= lane < BLOCK.

    Returns
    -------
    float
    """
    return a[i * BLOCK + lane]


@jit
def column3(a, i, lane):
    """Rows ``i..i+2`` of lane ``lane`` of a block's rows ``a``.

    Parameters
    ----------
    a : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    i : int
        The first row.
    lane : int
        The lane, 0 <= lane < BLOCK.

    Returns
    -------
    tuple of 3 floats
    """
    return (a[i * BLOCK + lane], a[(i + 1) * BLOCK + lane], a[(i + 2) * BLOCK + lane])


@jit
def column4(a, i, lane):
    """Rows ``i..i+3`` of lane ``lane`` of a block's rows ``a``.

    Parameters
    ----------
    a : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    i : int
        The first row.
    lane : int
        The lane, 0 <= lane < BLOCK.

    Returns
    -------
    tuple of 4 floats
    """
    return (
        a[i * BLOCK + lane],
        a[(i + 1) * BLOCK + lane],
        a[(i + 2) * BLOCK + lane],
        a[(i + 3) * BLOCK + lane],
    )


@jit
def set_column3(a, i, lane, v):
    """Store the 3-tuple ``v`` into rows ``i..i+2`` of lane ``lane`` (mutates ``a``).

    Parameters
    ----------
    a : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    i : int
        The first row.
    lane : int
        The lane, 0 <= lane < BLOCK.
    v : tuple of 3 floats
    """
    a[i * BLOCK + lane] = v[0]
    a[(i + 1) * BLOCK + lane] = v[1]
    a[(i + 2) * BLOCK + lane] = v[2]


@jit
def set_column4(a, i, lane, v):
    """Store the 4-tuple ``v`` into rows ``i..i+3`` of lane ``lane`` (mutates ``a``).

    Parameters
    ----------
    a : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    i : int
        The first row.
    lane : int
        The lane, 0 <= lane < BLOCK.
    v : tuple of 4 floats
    """
    a[i * BLOCK + lane] = v[0]
    a[(i + 1) * BLOCK + lane] = v[1]
    a[(i + 2) * BLOCK + lane] = v[2]
    a[(i + 3) * BLOCK + lane] = v[3]


# The helpers that take row numbers are inlined by numba: left to LLVM, a helper that it did not
# inline saw its rows as numbers known only at run time, could not tell them apart, and ran
# its loops one lane at a time, at half the speed.
@inline_jit
def quat_exp_columns(block, vector, quaternion):
    """`rbstudy.numerics.lanes_math.quat_exp_poly` of every lane's rotation vector, rows
    ``vector..vector+2`` of ``block`` (N_ROWS * BLOCK,), into rows ``quaternion..quaternion+3``:
    a loop over lanes that vectorises, then, where any lane's half angle is past
    `rbstudy.numerics.lanes_math.REDUCED` (or NaN), libm's sine for those lanes, as `sin_cos`
    takes it.

    Parameters
    ----------
    block : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    vector, quaternion : int
        The first rows of the rotation vectors (3 rows) and of their quaternions (4 rows).
    """
    outside = False
    for lane in range(BLOCK):
        v = column3(block, vector, lane)
        angle = norm(v)
        sine, cosine = sin_cos_reduced(0.5 * angle)
        set_column4(block, quaternion, lane, quat_exp_of(v, angle, sine, cosine))
        outside |= not abs(0.5 * angle) <= REDUCED
    # only where a lane needs it: the scalar loop over every lane cost a third of the
    # exponential's time
    if outside:
        for lane in range(BLOCK):
            v = column3(block, vector, lane)
            angle = norm(v)
            half = 0.5 * angle
            if not abs(half) <= REDUCED:
                set_column4(block, quaternion, lane, quat_exp_of(v, angle, math.sin(half), math.cos(half)))


@inline_jit
def sin_cos_columns(block, angle):
    """`rbstudy.numerics.lanes_math.sin_cos` of every lane's angle, row ``angle`` of ``block``
    (N_ROWS * BLOCK,), into rows ``angle + 1`` (sine) and ``angle + 2`` (cosine): a loop over
    lanes that vectorises, then libm's for the angles past `REDUCED` (or NaN), as `sin_cos`
    takes them.

    Parameters
    ----------
    block : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    angle : int
        The row of the angles (rad), then 2 rows of scratch (`SIN_COS_ROWS` in all).
    """
    for lane in range(BLOCK):
        sine, cosine = sin_cos_reduced(at(block, angle, lane))
        block[(angle + 1) * BLOCK + lane] = sine
        block[(angle + 2) * BLOCK + lane] = cosine
    for lane in range(BLOCK):
        x = at(block, angle, lane)
        if not abs(x) <= REDUCED:
            block[(angle + 1) * BLOCK + lane] = math.sin(x)
            block[(angle + 2) * BLOCK + lane] = math.cos(x)


@inline_jit
def start_newton(block, rows):
    """Before an implicit block step's Newton iterations: row ``rows`` (whether a lane
    iterates) 1.0 for the lanes booked that have not failed in this step (an earlier stage of a
    composition), rows ``rows + 1`` (whether it converged) and ``rows + 2`` (its iterations)
    0.0.

    Parameters
    ----------
    block : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    rows : int
        The first of the three rows.
    """
    for lane in range(BLOCK):
        live = (at(block, LIVE, lane) != 0.0) & (at(block, VERDICT, lane) == OK)
        block[rows * BLOCK + lane] = 1.0 if live else 0.0
        block[(rows + 1) * BLOCK + lane] = 0.0
        block[(rows + 2) * BLOCK + lane] = 0.0


@inline_jit
def end_newton(block, rows):
    """After an implicit block step's Newton iterations: `VERDICT` NOT_CONVERGED for the
    lanes that were still OK and did not converge, and their iterations added to
    `ITERATIONS`.

    Parameters
    ----------
    block : ndarray, shape (N_ROWS * BLOCK,)
        The rows of the block whose step ends.
    rows : int
        The first of the rows of `start_newton`, as the iterations left them.
    """
    for lane in range(BLOCK):
        failed = (at(block, VERDICT, lane) == OK) & (at(block, rows + 1, lane) == 0.0)
        block[VERDICT * BLOCK + lane] = NOT_CONVERGED if failed else at(block, VERDICT, lane)
        block[ITERATIONS * BLOCK + lane] += at(block, rows + 2, lane)


@inline_jit
def turn_columns(block, vector):
    """Turn every lane's orientation by the rotation vector in rows ``vector..vector+2`` of
    ``block`` (N_ROWS * BLOCK,): ``q <- normalise(q exp(vector))``, the exponential into the
    four rows after the vector (`quat_exp_columns`).

    Parameters
    ----------
    block : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    vector : int
        The first of the rotation vectors' rows (rad), 3 rows, then 4 rows of scratch
        (`TURN_ROWS` in all).
    """
    quat_exp_columns(block, vector, vector + 3)
    for lane in range(BLOCK):
        q = column4(block, STATE + S.QUATERNION, lane)
        turn = column4(block, vector + 3, lane)
        set_column4(block, STATE + S.QUATERNION, lane, quat_normalize(quat_mul(q, turn)))


@jit
def loads_at(block, q, w, lane):
    """The loads on lane ``lane`` of a block at orientation ``q``, spin ``w``: ``(moment, mass,
    force)``, the body-frame moment (N m) and the space force (N) as
    `rbstudy.numerics.dynamics.body_moment` and `space_force` give them for `plain_loads`.

    Parameters
    ----------
    block : ndarray, shape (N_ROWS * BLOCK,)
        A block's rows.
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    w : tuple of 3 floats
        Angular velocity, rad/s, body axes.
    lane : int
        The lane.

    Returns
    -------
    moment : tuple of 3 floats
        N m, body axes.
    mass : float
        kg.
    force : tuple of 3 floats
        N, space axes.
    """
    body, space = column3(block, PARAM + S.MOMENT_BODY, lane), column3(block, PARAM + S.MOMENT_SPACE, lane)
    mass = at(block, PARAM + S.MASS, lane)
    weight, force = column3(block, PARAM + S.GRAVITY, lane), column3(block, PARAM + S.FORCE_SPACE, lane)
    return moment_from(q, w, block, None, body, space), mass, force_from(q, block, None, mass, weight, force)
