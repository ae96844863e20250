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

What the block path covers, and what it hands back
--------------------------------------------------
`run_blocks` steps the bodies of a batch without loads tabulated in time (the kernels without
the time, `rbstudy.numerics.clock`) whose loads are constant and act at the centre of mass or
as moments, of the kinds the load catalogue says the blocks carry
(`rbstudy.numerics.loads.LoadKind.in_blocks`, read by `loads_at`): no lever and no body-fixed
force, whose branches would keep the loop over lanes from vectorising; in blocks of at least
`FEWEST` bodies. Other blocks run through the single-body loop
(`rbstudy.numerics.driver.run_rows`), which gives the same bits.

Every lane is stepped every step; a body that has failed stops being booked (its status
is no longer OK), so its state may go on to NaN without effect: nothing passes between lanes,
and no lane's arithmetic traps. The lanes past the last body of the batch are copies of the
block's first body that are never booked. The bookkeeping follows
`rbstudy.numerics.lanes.lane_after_step` step for step (`_book`: the same tests in the same
order, written with selects in a loop over lanes that vectorises); only the samples are stored
lane by lane.
"""

import math

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.numerics.dynamics import force_from, moment_from, momentum_squared, rotational_energy
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes import HALT_MASK, IDLE, lane_end, lane_start, relative_drift
from rbstudy.numerics.lanes_math import REDUCED, sin_cos_reduced
from rbstudy.numerics.loads import BLOCKLESS_SLOTS
from rbstudy.numerics.rotation import dot, norm, quat_exp_of, quat_mul, quat_normalize
from rbstudy.numerics.state import NOT_CONVERGED, OK, UNSTABLE

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
    "run_blocks",
    "run_rows_in_blocks",
    "plain_loads",
    "quat_exp_columns",
    "sin_cos_columns",
    "start_newton",
    "end_newton",
]

# Bodies stepped together. 8 fill one AVX-512 register of doubles, but LLVM here picks 4-wide
# (AVX2) registers and each loop over lanes has its set-up: a block of 8 ran leapfrog at
# 4.0e7 body-steps/s, of 16 at 8.3e7, the same as 1e4 (one core, measured); 64 leaves the
# loop set-up nothing and still fits L1 (13 + N_PARAM + N_TEMP rows of 512 bytes).
BLOCK = 64
# The fewest bodies worth a block: a block steps all its lanes, filled or not, in about the time
# the single-body loop takes for 16 bodies (leapfrog: 64 lanes at 9e7 lane-steps/s against
# 2.5e7 body-steps/s), so fewer run there (a batch of one body ran 40 times slower in a block).
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

# Rows of a block's tallies, the fields of the driver's lane tuple (`_book`): status, steps
# taken, Newton iterations, largest energy and |L| drifts, largest |w|^2, next sample (floats,
# so that one loop over lanes handles them all).
_STATUS, _STEPS, _ITERATIONS, _MAX_ENERGY, _MAX_MOMENTUM, _SPIN, _SAMPLE = range(7)
_N_TALLY = 7


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
# its loops one lane at a time (leapfrog 9.0e7 -> 4.4e7 body-steps/s, measured).
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
    # only where a lane needs it: the scalar loop cost 1.5 ns a lane, 30% of the exponential
    # (block steps alone, one core: rkmk4's 2.4e7 -> 2.9e7 lane-steps/s, euler's 1.15e8 -> 1.43e8)
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


@jit
def plain_loads(p):
    """Whether the block path covers a body: no load of a kind it does not carry
    (`rbstudy.numerics.loads.BLOCKLESS_SLOTS`: the lever and the body-fixed force, whose
    branches would keep the loop over lanes from vectorising, and the kinds of the timed
    kernels alone).

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM.

    Returns
    -------
    bool
    """
    for start, width in BLOCKLESS_SLOTS:
        for k in range(width):
            if p[start + k] != 0.0:
                return False
    return True


@jit
def _plain_block(params, options, a, stop):
    """Whether every body of rows [a, stop) has `plain_loads` and the option row of row ``a``."""
    for row in range(a, stop):
        if not plain_loads(params[row]):
            return False
        for k in range(options.shape[1]):
            if options[row, k] != options[a, k]:
                return False
    return True


@jit
def _load_block(a, stop, state0, params, block):
    """Copy the rows [a, stop) of the batch into the block's lanes; the lanes past ``stop``
    copy row ``a``."""
    for lane in range(BLOCK):
        row = a + lane if a + lane < stop else a
        for k in range(S.N_STATE):
            block[(STATE + k) * BLOCK + lane] = state0[row, k]
        for k in range(S.N_PARAM):
            block[(PARAM + k) * BLOCK + lane] = params[row, k]
        block[VERDICT * BLOCK + lane] = OK
        block[ITERATIONS * BLOCK + lane] = 0.0
        block[LIVE * BLOCK + lane] = 1.0 if a + lane < stop else 0.0


@jit
def _load_lane(block, lane, y, work):
    """Store a body's state row ``y`` (N_STATE,) and the first `CARRIED` floats of its
    ``work`` (n_work,) in lane ``lane`` of a block."""
    for k in range(S.N_STATE):
        block[(STATE + k) * BLOCK + lane] = y[k]
    for k in range(min(CARRIED, work.shape[0])):
        block[(WORK + k) * BLOCK + lane] = work[k]


@jit
def _book(block, lanes, fixed, drift_bound):
    """Book the step every lane has just taken, as `rbstudy.numerics.lanes.lane_after_step`
    books one body's: the same tests in the same order, written with selects so that the loop
    over lanes vectorises; row `LIVE` then says which lanes are still booked, and rows
    `VERDICT` and `ITERATIONS` are OK and 0 again for the next step. Returns how many bodies
    failed on this step.

    Parameters
    ----------
    block : ndarray, shape (N_ROWS * BLOCK,)
        The block's rows after the step, with the step's `VERDICT` and `ITERATIONS`.
    lanes : ndarray of float, shape (_N_TALLY * BLOCK,)
        Each lane's tallies, row by row (`_STATUS`...), updated for the lanes still OK.
    fixed : ndarray of float, shape (3 * BLOCK,)
        Each body's energy and |L| at t = 0 and 1.0 where they must hold.
    drift_bound : float
        Relative energy or |L| drift that flags a moment-free body unstable.
    """
    failed = 0
    for lane in range(BLOCK):
        total = 0.0
        for k in range(S.N_STATE):
            total += block[(STATE + k) * BLOCK + lane]
        w = column3(block, STATE + S.OMEGA, lane)
        inertia_ = column3(block, PARAM + S.INERTIA, lane)
        d_energy = relative_drift(rotational_energy(w, inertia_), fixed[0 * BLOCK + lane])
        d_momentum = relative_drift(math.sqrt(momentum_squared(w, inertia_)), fixed[1 * BLOCK + lane])
        spin = dot(w, w)
        running = lanes[_STATUS * BLOCK + lane] == OK
        verdict = block[VERDICT * BLOCK + lane]
        finite = running & (verdict == OK) & math.isfinite(total)
        checked = finite & (fixed[2 * BLOCK + lane] != 0.0)
        # written so that NaN drifts also fail the test
        within = (d_energy <= drift_bound) & (d_momentum <= drift_bound)
        ok = finite & (within | (fixed[2 * BLOCK + lane] == 0.0))
        lanes[_STEPS * BLOCK + lane] += 1.0 if running else 0.0
        lanes[_ITERATIONS * BLOCK + lane] += block[ITERATIONS * BLOCK + lane] if running else 0.0
        lanes[_MAX_ENERGY * BLOCK + lane] = (
            max(lanes[_MAX_ENERGY * BLOCK + lane], d_energy) if checked else lanes[_MAX_ENERGY * BLOCK + lane]
        )
        lanes[_MAX_MOMENTUM * BLOCK + lane] = (
            max(lanes[_MAX_MOMENTUM * BLOCK + lane], d_momentum)
            if checked
            else lanes[_MAX_MOMENTUM * BLOCK + lane]
        )
        lanes[_SPIN * BLOCK + lane] = (
            spin if ok & (spin > lanes[_SPIN * BLOCK + lane]) else lanes[_SPIN * BLOCK + lane]
        )
        failure = verdict if verdict != OK else UNSTABLE
        lanes[_STATUS * BLOCK + lane] = OK if ok else (failure if running else lanes[_STATUS * BLOCK + lane])
        block[LIVE * BLOCK + lane] = 1.0 if ok else 0.0
        block[VERDICT * BLOCK + lane] = OK
        block[ITERATIONS * BLOCK + lane] = 0.0
        failed += 1 if running & (not ok) else 0
    return failed


@jit
def _store_column(samples, b, sample, block, lane):
    """Write lane ``lane``'s state as sample ``sample`` of body ``b``."""
    for k in range(S.N_STATE):
        samples[b, sample, k] = block[(STATE + k) * BLOCK + lane]


@inline_jit
def run_blocks(
    block_step,
    init,
    n_work,
    a,
    stop,
    state0,
    params,
    opt,
    h,
    n_steps,
    every,
    drift_bound,
    samples,
    results,
    halt,
):
    """Integrate rows [a, stop) of a batch, at most `BLOCK` of them, with a scheme's block
    step; write their samples and results as `rbstudy.numerics.driver.run_rows` does.

    Parameters
    ----------
    block_step : compiled kernel ``(block, opt, h)``
        The scheme's (module docstring).
    init : compiled kernel ``(y, p, opt, t, h, work) -> status``
        The scheme's start of a body (`rbstudy.numerics.entry.make_entry`), run on each lane.
    n_work : int
        Floats of work per body.
    a, stop : int
        The rows, ``stop - a <= BLOCK``, each of `plain_loads`.
    state0 : ndarray, shape (B, N_STATE)
        Initial states (read only).
    params : ndarray, shape (B, W)
        Parameter rows, W >= N_PARAM.
    opt : ndarray, shape (N_OPTION,)
        The option row of every body of the rows.
    h : float
        Time step (s).
    n_steps : int
        Steps of every body.
    every : int
        Steps between two samples.
    drift_bound : float
        Relative energy or |L| drift that flags a moment-free body unstable.
    samples : ndarray, shape (B, T, N_STATE)
        Output; NaN after a body's failure.
    results : ndarray, shape (B, N_RESULT)
        Output, by name (`rbstudy.numerics.state.Result`).
    halt : ndarray of int64, shape (1,)
        The halt flag.
    """
    block = np.empty(N_ROWS * BLOCK)
    lanes = np.zeros(_N_TALLY * BLOCK)
    lanes[_STATUS * BLOCK : (_STATUS + 1) * BLOCK] = IDLE
    fixed = np.zeros(3 * BLOCK)
    _load_block(a, stop, state0, params, block)
    running = 0
    y, work = np.empty(S.N_STATE), np.empty(n_work)
    for lane in range(BLOCK):
        row = a + lane if a + lane < stop else a
        if lane < stop - a:
            start, lane_tuple = lane_start(row, state0[row], params[row], samples)
            fixed[0 * BLOCK + lane], fixed[1 * BLOCK + lane], fixed[2 * BLOCK + lane] = (
                start[0],
                start[1],
                1.0 if start[2] else 0.0,
            )
            lanes[_SPIN * BLOCK + lane] = lane_tuple[5]
            lanes[_SAMPLE * BLOCK + lane] = 1.0
        # the scheme's start, on the lane's rows as the single-body loop gives it a body's
        y[:] = state0[row]
        work[:] = 0.0
        status = init(y, params[row], opt, None, h, work)
        _load_lane(block, lane, y, work)
        if lane < stop - a:
            lanes[_STATUS * BLOCK + lane] = status
            block[LIVE * BLOCK + lane] = 1.0 if status == OK else 0.0
            running += 1 if status == OK else 0
    countdown = every
    for step in range(n_steps):
        if running == 0:
            break
        if (step & HALT_MASK) == 0 and halt[0] != 0:
            break
        countdown -= 1
        block_step(block, opt, h)
        running -= _book(block, lanes, fixed, drift_bound)
        if countdown == 0:
            countdown = every
            for lane in range(stop - a):
                if lanes[_STATUS * BLOCK + lane] == OK:
                    _store_column(samples, a + lane, int(lanes[_SAMPLE * BLOCK + lane]), block, lane)
                    lanes[_SAMPLE * BLOCK + lane] += 1.0
    for lane in range(stop - a):
        tallies = (
            int(lanes[_STATUS * BLOCK + lane]),
            int(lanes[_STEPS * BLOCK + lane]),
            int(lanes[_ITERATIONS * BLOCK + lane]),
            lanes[_MAX_ENERGY * BLOCK + lane],
            lanes[_MAX_MOMENTUM * BLOCK + lane],
            lanes[_SPIN * BLOCK + lane],
            int(lanes[_SAMPLE * BLOCK + lane]),
        )
        lane_end(
            tallies,
            (fixed[0 * BLOCK + lane], fixed[1 * BLOCK + lane], fixed[2 * BLOCK + lane] != 0.0),
            a + lane,
            h,
            samples,
            results,
        )


@inline_jit
def run_rows_in_blocks(
    block_step,
    init,
    n_work,
    single,
    start,
    stop,
    state0,
    params,
    options,
    h,
    n_steps,
    every,
    drift_bound,
    samples,
    results,
    halt,
):
    """Integrate the rows [start, stop) of a batch without loads tabulated in time, `BLOCK` at a
    time: with ``block_step`` (`run_blocks`) where the block has at least `FEWEST` bodies, every
    one has `plain_loads` and all share one option row, with ``single`` elsewhere: the scheme's
    entry point of the single-body loop (`rbstudy.numerics.driver.run_rows`), ``single(start,
    stop, state0, params, options, h, n_steps, every, drift_bound, samples, results, halt,
    clock)``.

    Parameters
    ----------
    block_step : compiled kernel ``(block, opt, h)``
        The scheme's (module docstring).
    init : compiled kernel ``(y, p, opt, t, h, work) -> status``
        The scheme's start of a body.
    n_work : int
        Floats of work per body.
    single : compiled function
        The single-body loop over a range of rows, as above.
    start, stop : int
        The rows to integrate; only these rows of ``samples`` and ``results`` are written.
    state0 : ndarray, shape (B, N_STATE)
        Initial states (read only).
    params : ndarray, shape (B, W)
        Parameter rows, W >= N_PARAM.
    options : ndarray, shape (B, N_OPTION)
        Scheme options (read only).
    h : float
        Time step (s).
    n_steps : int
        Steps of every body.
    every : int
        Steps between two samples.
    drift_bound : float
        Relative energy or |L| drift that flags a moment-free body unstable.
    samples : ndarray, shape (B, T, N_STATE)
        Output; NaN after a body's failure.
    results : ndarray, shape (B, N_RESULT)
        Output, by name (`rbstudy.numerics.state.Result`).
    halt : ndarray of int64, shape (1,)
        The halt flag.
    """
    for a in range(start, stop, BLOCK):
        if halt[0] != 0:
            return
        end = min(a + BLOCK, stop)
        if end - a >= FEWEST and _plain_block(params, options, a, end):
            shared, bound = options[a], drift_bound  # the option row of every body of the block
            run_blocks(
                block_step,
                init,
                n_work,
                a,
                end,
                state0,
                params,
                shared,
                h,
                n_steps,
                every,
                bound,
                samples,
                results,
                halt,
            )
        else:
            single(
                a, end, state0, params, options, h, n_steps, every, drift_bound, samples, results, halt, None
            )
