"""The single-body loop: the bodies of a range of batch rows stepped one at a time, or two side
by side (a scheme's ``lanes``), through all their steps with a scheme's kernels
(`rbstudy.numerics.driver` says how a scheme plugs in), each step booked as
`rbstudy.numerics.lanes` books it.

numba inlines `run_rows` and `integrate_rows_inplace` into each scheme's entry point
(`rbstudy.numerics.entry.make_entry`, `inline_jit`): the kernels are then never passed as
values, which numba could not cache. The loop writes element by element and allocates nothing;
`integrate_rows_inplace` allocates its bodies' state and work arrays before it.
"""

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.numerics.clock import step_time
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes import (
    HALT_MASK,
    IDLE,
    SAMPLE,
    lane_after_step,
    lane_end,
    lane_start,
    state_sum,
    store_sample,
    with_status,
)
from rbstudy.numerics.rotation import read3
from rbstudy.numerics.state import OK

__all__ = ["idle_step", "integrate_rows_inplace", "run_rows"]


@jit
def idle_step(y, p, opt, t, h, work):
    """The step of a second lane that never runs (`run_rows` of a scheme of one lane).

    Parameters
    ----------
    y : ndarray, shape (N_STATE,)
        The body's state row.
    p : ndarray, shape (W,)
        Its parameter row, W >= N_PARAM.
    opt : ndarray, shape (N_OPTION,)
        Its scheme options.
    t : float or None
        Time at the start of the step (s); None without loads tabulated in time.
    h : float
        Time step (s).
    work : ndarray, shape (n_work,)
        The body's scratch and carry.

    Returns
    -------
    status : int
        -1, the idle lane's status (never OK, never stored).
    iterations : int
        0.
    """
    return IDLE, 0


# longer than the limit: one hot loop over two lanes, each written out (the comment in the loop
# says why a helper per lane would be slower); half of it is its docstring
@inline_jit
def integrate_rows_inplace(
    step,
    init,
    second_step,
    second_init,
    n_work,
    a,
    b,
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
    clock,
):
    """Integrate body ``a`` of a batch, and body ``b`` beside it step for step unless ``b`` is
    -1; write their samples and results.

    Why two at once (a scheme's ``lanes``, `rbstudy.numerics.entry.make_entry`): the step of
    a cheap scheme is a chain of dependent operations (the moment needs the orientation, the
    spin the moment, the rotation the spin: divisions, square roots, a sine), and one body's
    chain leaves the core idle while each result waits on the last. Two independent chains in
    one loop let the core overlap them (`rbstudy bench` shows the rates). Each
    body keeps its own state, work and tallies; nothing passes
    between the lanes, so a body's numbers are the same in any pair, or alone.

    Parameters
    ----------
    step, init : compiled kernels
        One scheme's (module docstring), for body ``a``.
    second_step, second_init : compiled kernels
        The kernels for body ``b`` (`run_rows`).
    n_work : int
        Floats of work per body.
    a, b : int
        The bodies' rows in the batch arrays (``b`` -1 for none); only these rows of
        ``samples`` and ``results`` are written.
    state0 : ndarray, shape (B, N_STATE)
        Initial states (read only).
    params : ndarray, shape (B, W)
        Parameter rows, W >= N_PARAM (`rbstudy.numerics.state.row_width`).
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
        Output, T = n_steps // every + 1 (`n_samples`); NaN after a body's failure.
    results : ndarray, shape (B, N_RESULT)
        Output, by name (`rbstudy.numerics.state.Result`): the drifts NaN under moments, the
        failure time NaN for a body that finished; the largest step angle dt |w| and the
        Radioss flag cover every step taken.
    halt : ndarray of int64, shape (1,)
        The halt flag: the bodies stop early when it is nonzero (their numbers are then
        discarded by `run_batch`).
    clock : float or None
        0.0 to give the kernels the time, None to compile them without it
        (`rbstudy.numerics.clock`).
    """
    paired = b >= 0
    ya, work_a = state0[a].copy(), np.zeros(n_work)
    # an idle second lane never steps: it may name the first lane's arrays
    yb, work_b = (state0[b].copy(), np.zeros(n_work)) if paired else (ya, work_a)
    pa, pb = params[a], params[b if paired else a]
    oa, ob = options[a], options[b if paired else a]
    fixed_a, lane_a = lane_start(a, ya, pa, samples)
    lane_a = with_status(lane_a, init(ya, pa, oa, step_time(0, h, clock), h, work_a))
    fixed_b, lane_b = fixed_a, with_status(lane_a, IDLE)
    if paired:
        fixed_b, lane_b = lane_start(b, yb, pb, samples)
        lane_b = with_status(lane_b, second_init(yb, pb, ob, step_time(0, h, clock), h, work_b))
    countdown = every  # steps to the next sample
    for steps_done in range(n_steps):
        if lane_a[0] != OK and lane_b[0] != OK:
            break
        if (steps_done & HALT_MASK) == 0 and halt[0] != 0:
            break
        countdown -= 1
        due = countdown == 0
        if due:
            countdown = every
        # the two lanes written out, not a helper called twice: a helper would take the
        # kernel and the arrays, so numba would inline it, and arrays passed to an inlined
        # function are reference counted on every step (see `lane_after_step`)
        if lane_a[0] == OK:
            status, iters = step(ya, pa, oa, step_time(steps_done, h, clock), h, work_a)
            lane_a = lane_after_step(
                lane_a,
                fixed_a,
                status,
                iters,
                state_sum(ya),
                read3(ya, S.OMEGA),
                read3(pa, S.INERTIA),
                drift_bound,
                due,
            )
            if due and lane_a[0] == OK:
                store_sample(samples, a, lane_a[SAMPLE] - 1, ya)
        if lane_b[0] == OK:
            status, iters = second_step(yb, pb, ob, step_time(steps_done, h, clock), h, work_b)
            lane_b = lane_after_step(
                lane_b,
                fixed_b,
                status,
                iters,
                state_sum(yb),
                read3(yb, S.OMEGA),
                read3(pb, S.INERTIA),
                drift_bound,
                due,
            )
            if due and lane_b[0] == OK:
                store_sample(samples, b, lane_b[SAMPLE] - 1, yb)
    lane_end(lane_a, fixed_a, a, h, samples, results)
    if paired:
        lane_end(lane_b, fixed_b, b, h, samples, results)


@inline_jit
def run_rows(
    step,
    init,
    second_step,
    second_init,
    n_work,
    lanes,
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
    clock,
):
    """Integrate the rows [start, stop) of a batch with a scheme's kernels, ``lanes`` rows at a
    time (`integrate_rows_inplace`).

    The second lane runs ``second_step`` and ``second_init``: the scheme's own kernels for two
    lanes; for one, `idle_step` and `init_nothing`, which it never calls, so that a scheme of
    one lane compiles its step once, not twice.

    Parameters
    ----------
    step, init : compiled kernels
        The scheme's (`rbstudy.numerics.driver` says how a scheme plugs in).
    second_step, second_init : compiled kernels
        The second lane's.
    n_work : int
        Floats of work per body.
    lanes : int
        1 or 2.
    start, stop : int
        The rows to integrate; only these rows of ``samples`` and ``results`` are written.
    state0, params, options, h, n_steps, every, drift_bound, samples, results, halt, clock : any
        As `integrate_rows_inplace` takes them.
    """
    for a in range(start, stop, lanes):
        if halt[0] != 0:
            return
        b = a + 1 if lanes == 2 and a + 1 < stop else -1
        integrate_rows_inplace(
            step,
            init,
            second_step,
            second_init,
            n_work,
            a,
            b,
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
            clock,
        )
