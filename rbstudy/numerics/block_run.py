"""The block path's runs: which bodies of a batch go in blocks of `BLOCK` lanes
(`rbstudy.numerics.block` lays a block out and says how a scheme's block step works on it), and
each block's bookkeeping.

`run_blocks` steps the bodies of a batch without loads tabulated in time (the kernels without
the time, `rbstudy.numerics.clock`) whose loads are constant and act at the centre of mass or
as moments, of the kinds the load catalogue says the blocks carry
(`rbstudy.numerics.loads.LoadKind.in_blocks`, read by `rbstudy.numerics.block.loads_at`): no
lever and no body-fixed force, whose branches would keep the loop over lanes from vectorising;
in blocks of at least `FEWEST` bodies. Other blocks run through the single-body loop
(`rbstudy.numerics.rows.run_rows`), which gives the same bits.

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
from rbstudy.numerics.block import (
    BLOCK,
    CARRIED,
    FEWEST,
    ITERATIONS,
    LIVE,
    N_ROWS,
    PARAM,
    STATE,
    VERDICT,
    WORK,
    column3,
)
from rbstudy.numerics.dynamics import momentum_squared, rotational_energy
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes import HALT_MASK, IDLE, lane_end, lane_start, relative_drift
from rbstudy.numerics.loads import BLOCKLESS_SLOTS
from rbstudy.numerics.rotation import dot
from rbstudy.numerics.state import OK, UNSTABLE

__all__ = ["plain_loads", "run_blocks", "run_rows_in_blocks"]

# Rows of a block's tallies, the fields of the driver's lane tuple (`_book`): status, steps
# taken, Newton iterations, largest energy and |L| drifts, largest |w|^2, next sample (floats,
# so that one loop over lanes handles them all).
_STATUS, _STEPS, _ITERATIONS, _MAX_ENERGY, _MAX_MOMENTUM, _SPIN, _SAMPLE = range(7)
_N_TALLY = 7


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
def _start_lanes(init, n_work, a, stop, state0, params, opt, h, samples, block, lanes, fixed):
    """Start every lane of a block loaded with rows [a, stop) (`_load_block`): the scheme's
    ``init`` on each lane's rows, as the single-body loop gives it a body's, and each booked
    lane's tallies and fixed energy and |L| (`rbstudy.numerics.lanes.lane_start`). Inlined, as
    `run_blocks` is, for it takes a kernel. Returns how many bodies start OK."""
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
        y[:] = state0[row]
        work[:] = 0.0
        status = init(y, params[row], opt, None, h, work)
        _load_lane(block, lane, y, work)
        if lane < stop - a:
            lanes[_STATUS * BLOCK + lane] = status
            block[LIVE * BLOCK + lane] = 1.0 if status == OK else 0.0
            running += 1 if status == OK else 0
    return running


@jit
def _end_lanes(lanes, fixed, a, stop, h, samples, results):
    """Write the results of the block's bodies, rows [a, stop), from their tallies, as the
    single-body loop writes a body's (`rbstudy.numerics.lanes.lane_end`)."""
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
    step; write their samples and results as `rbstudy.numerics.rows.run_rows` does.

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
    running = _start_lanes(init, n_work, a, stop, state0, params, opt, h, samples, block, lanes, fixed)
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
    _end_lanes(lanes, fixed, a, stop, h, samples, results)


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
    entry point of the single-body loop (`rbstudy.numerics.rows.run_rows`), ``single(start,
    stop, state0, params, options, h, n_steps, every, drift_bound, samples, results, halt,
    clock)``.

    Parameters
    ----------
    block_step, init, n_work : any
        As `run_blocks` takes them.
    single : compiled function
        The single-body loop over a range of rows, as above.
    start, stop : int
        The rows to integrate; only these rows of ``samples`` and ``results`` are written.
    options : ndarray, shape (B, N_OPTION)
        Scheme options (read only).
    state0, params, h, n_steps, every, drift_bound, samples, results, halt : any
        As `run_blocks` takes them.
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
