"""The generic batch driver: B independent bodies, n fixed steps each, sampled every k steps.

How a scheme plugs in
---------------------
A scheme supplies two compiled single-body kernels,

    init_inplace(y, p, opt, t, h, work) -> status
    step_inplace(y, p, opt, t, h, work) -> (status, newton_iterations)

with ``y`` the body's state row (N_STATE,), ``p`` its parameter row (at least N_PARAM wide:
loads tabulated in time follow it, `rbstudy.numerics.state.KNOTS`), ``opt`` its scheme
options (N_OPTION,), ``t`` the time at the start of the step (s; the loads at a stage of the
step are taken at that stage's time, ``later(t, d)``; ``t`` is None in a batch without loads
tabulated in time, `rbstudy.numerics.clock`), and ``work`` a scratch/carry array (n_work,) that lives for the
whole run of that body (HHT keeps its acceleration there, NO_SQUISH its conjugate momentum).
The per-body results (`rbstudy.numerics.state.RESULT_FIELDS`: status, failure time, steps,
iterations, energy and |L| drift, the largest step angle and the Radioss flag) are filled
here, by name.

`integrate_rows_inplace` below runs one body, or two side by side (a scheme's ``lanes``),
through all their steps, booking each step as `rbstudy.numerics.lanes` does, and `run_rows` a
range of batch rows; `rbstudy.numerics.entry.make_entry` gives a scheme its entry point, a
cached function that calls `run_rows` with the scheme's kernels; `run_batch` spreads chunks
of rows over threads (the kernels release the GIL). numba inlines `run_rows` and
`integrate_rows_inplace` into each entry point (`inline_jit`): the kernels are then never
passed as values, which numba could not cache. The loop writes element by element and
allocates nothing; `integrate_rows_inplace` allocates its bodies' state and work arrays
before it. Threads rather than numba's `prange` keep the kernels safe to call from several
dask worker threads at once and let the caller choose the number of cores.

A run can be halted from outside: `request_halt` sets a flag that every body's loop reads
every `rbstudy.numerics.lanes.HALT_CHECK_STEPS` steps (a few milliseconds of work at most),
so that Ctrl-C ends even a batch of 1e12 steps at once; `run_batch` then raises `Halted`
instead of returning partial numbers. The flag is an array the compiled loops read from
memory, not a constant they could keep in a register.

Failure is data, never an exception: a body whose state turns non-finite, or whose energy or
angular momentum drifts past ``drift_bound`` while no moment acts, stops with status
``UNSTABLE`` and its failure time; an implicit step whose Newton iteration does not converge
stops with ``NOT_CONVERGED``. Its later samples are NaN. Other bodies are unaffected, and a
body's numbers do not depend on which batch it ran in (no cross-body operations).
"""

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

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
from rbstudy.numerics.loads import needs_time
from rbstudy.numerics.machine import default_threads
from rbstudy.numerics.rotation import read3
from rbstudy.numerics.state import OK, Result

__all__ = [
    "DRIFT_BOUND",
    "BatchOutput",
    "init_nothing",
    "idle_step",
    "integrate_rows_inplace",
    "run_rows",
    "run_batch",
    "n_samples",
    "Halted",
    "request_halt",
    "clear_halt",
    "HALT_FLAG",
    "StatusError",
    "check_statuses",
]

# Relative drift of the rotational energy or of |L| beyond which a moment-free body counts as
# blown up. Half its size is far outside any accurate run (accurate runs sit below 1e-2) and
# well before overflow, so a diverging explicit scheme is stopped while its numbers are finite.
DRIFT_BOUND = 0.5

# Chunks of rows handed to each thread of `run_batch`.
_CHUNKS_PER_THREAD = 4

# The halt flag of this process: nonzero once `request_halt` is called.
HALT_FLAG = np.zeros(1, dtype=np.int64)


class Halted(Exception):
    """A batch stopped by `request_halt` before its end: it has no results."""


class StatusError(ValueError):
    """A scheme gave a body a status that is none of the codes of `state.STATUS_NAMES`."""


def check_statuses(codes):
    """Refuse codes that are not status codes: cast to an integer, NaN and codes past the table
    would be read as another status (NaN to ``int8`` is 0, "ok").

    Parameters
    ----------
    codes : scalar, or ndarray of any type, shape (...)
        What a scheme returned as statuses.

    Raises
    ------
    StatusError
        Naming the first code that is none of `rbstudy.numerics.state.STATUS_NAMES`.
    """
    codes = np.asarray(codes)
    # integers, the usual answer, in two reductions: 1.5 us a step of a vectorised scheme
    # where np.isin takes 12 us (of a step's ~140 us for one body)
    if codes.dtype.kind in "iu" and (
        codes.size == 0 or (codes.min() >= 0 and codes.max() < len(S.STATUS_NAMES))
    ):
        return
    known = np.isin(codes, np.arange(len(S.STATUS_NAMES)))
    if not known.all():
        listed = ", ".join(f"{code} ({name})" for code, name in enumerate(S.STATUS_NAMES))
        raise StatusError(
            f"returned the status {codes[~known].ravel().tolist()[0]!r}, which is not a status code: {listed}"
        )


def request_halt():
    """Make every running and later batch of this process stop within `HALT_CHECK_STEPS`
    steps and raise `Halted` (Ctrl-C)."""
    HALT_FLAG[0] = 1


def clear_halt():
    """Let batches run again (a new sweep in the same process)."""
    HALT_FLAG[0] = 0


def n_samples(n_steps, every):
    """Number of output samples, t = 0 included, of a run sampled every ``every`` steps.

    Parameters
    ----------
    n_steps : int
        Steps of the run.
    every : int
        Steps between two samples.

    Returns
    -------
    int
        T, the samples' axis length.
    """
    return n_steps // every + 1


@jit
def init_nothing(y, p, opt, t, h, work):
    """The ``init_inplace`` of schemes that carry nothing between steps.

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
    int
        OK.
    """
    return OK


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
    chain leaves the core idle while each result waits on the last. Two independent chains in one loop let
    the core overlap them (leapfrog 1.96e7 -> 2.5e7 body-steps/s on one core,
    docs/performance.md). Each body keeps its own state, work and tallies; nothing passes
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
    one lane compiles its step once, not twice (+40% of its compile time, measured).

    Parameters
    ----------
    step, init : compiled kernels
        The scheme's (module docstring).
    second_step, second_init : compiled kernels
        The second lane's.
    n_work : int
        Floats of work per body.
    lanes : int
        1 or 2.
    start, stop : int
        The rows to integrate; only these rows of ``samples`` and ``results`` are written.
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


@dataclass(frozen=True)
class BatchOutput:
    """What the driver returns for a batch of B bodies sampled at T times.

    samples : (B, T, N_STATE) sampled states (NaN after a failure).
    results : name -> (B,) array of its storage type, one per `RESULT_FIELDS` entry: status,
        failure_time (s), n_steps, iterations, max_energy_error and max_momentum_magnitude_error
        (largest relative drifts over every step; NaN for bodies under a moment).
    kernel_seconds : wall time of the compiled batch call, compilation excluded.
    kernel_cpu_seconds : CPU time of the threads inside the compiled calls, summed: the
        batch's cost in core-seconds, not inflated by other threads holding the GIL.
    """

    samples: np.ndarray
    results: dict
    kernel_seconds: float
    kernel_cpu_seconds: float


class BatchKernel(Protocol):
    """What `run_batch` needs of a scheme (a `rbstudy.schemes.Scheme`, which this layer does
    not import): its name, its entry point over a range of rows, and a way to compile it."""

    name: str
    run_bodies_inplace: Callable

    def ensure_compiled(self, timed: bool = False) -> None:
        """Compile (or load from the cache) the kernels before the clock starts.

        Parameters
        ----------
        timed : bool
            Whether the kernels that take the time (loads tabulated in time) are needed.
        """


def _as_rows(array, width, name, wider=False):
    """``array`` as C-ordered float rows (B, width), or at least ``width`` wide."""
    rows = np.ascontiguousarray(array, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] < width or (rows.shape[1] != width and not wider):
        raise ValueError(
            f"`{name}` must have shape (B, {width}{' or more' if wider else ''}), got {rows.shape}"
        )
    return rows


def _check_knots(params):
    """Refuse parameter rows too narrow for the knots they announce (`S.KNOTS`)."""
    knots = params[:, S.KNOTS]
    if np.any((knots < 0) | (knots != np.round(knots))):
        raise ValueError(
            f"`params` announce knot counts {sorted(set(knots.tolist()))}: each must be a whole number >= 0"
        )
    if np.any(S.row_width(knots) > params.shape[1]):
        raise ValueError(
            f"`params` rows of width {params.shape[1]} cannot hold the {int(knots.max())} knots they announce"
        )


def _chunks(n_bodies, threads, align=2):
    """Contiguous row ranges: a few per thread, so that early blow-ups do not idle a core;
    each a multiple of ``align`` long but the last: 2, so that a scheme of two lanes leaves no
    body of a range without its mate (`integrate_rows_inplace`); a block's width for a scheme
    that steps blocks, so that its ranges fill them (`rbstudy.numerics.block`)."""
    pieces = min(-(-n_bodies // align), threads * _CHUNKS_PER_THREAD) if threads > 1 else 1
    edges = np.linspace(0, n_bodies, pieces + 1).astype(int)
    edges[1:-1] -= edges[1:-1] % align
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def run_batch(
    scheme: BatchKernel,
    state0: np.ndarray,
    params: np.ndarray,
    options: np.ndarray,
    h: float,
    n_steps: int,
    every: int,
    drift_bound: float = DRIFT_BOUND,
    threads: int | None = None,
) -> BatchOutput:
    """Run a batch with a registered scheme and return a `BatchOutput`.

    The first call of a scheme in a process compiles (or loads from cache) before the clock
    starts, so ``kernel_seconds`` is run time only.

    Parameters
    ----------
    scheme : BatchKernel
        A registered scheme (`rbstudy.schemes.Scheme`), or anything with its kernels.
    state0 : ndarray, shape (B, N_STATE)
        Initial states.
    params : ndarray, shape (B, W)
        Parameter rows, W >= N_PARAM.
    options : ndarray, shape (B, N_OPTION)
        Scheme options.
    h : float
        Time step (s).
    n_steps : int
        Steps, >= 0.
    every : int
        Steps per sample, >= 1.
    drift_bound : float
        See `DRIFT_BOUND`.
    threads : int, optional
        Threads to spread the bodies over (default: all cores; 1 under a scheduler that
        already runs one task per core).

    Returns
    -------
    BatchOutput
        The samples (B, T, N_STATE), T = n_steps // every + 1, and the results (B,) by name.

    Raises
    ------
    Halted
        When `request_halt` was called before the batch ended.
    """
    state0 = _as_rows(state0, S.N_STATE, "state0")
    params = _as_rows(params, S.N_PARAM, "params", wider=True)
    _check_knots(params)
    options = _as_rows(options, S.N_OPTION, "options")
    if not (state0.shape[0] == params.shape[0] == options.shape[0]):
        raise ValueError("`state0`, `params` and `options` must have the same number of rows")
    n_steps, every = int(n_steps), int(every)
    if n_steps < 0 or every < 1:
        raise ValueError(f"need n_steps >= 0 and every >= 1, got {n_steps}, {every}")
    n_bodies = state0.shape[0]
    samples = np.empty((n_bodies, n_samples(n_steps, every), S.N_STATE))
    results = np.full((n_bodies, S.N_RESULT), np.nan)
    # the kernels take the time only where some body has loads tabulated in time, or a kind of
    # load only those kernels carry: a batch of the common loads runs kernels compiled
    # without it (`rbstudy.numerics.clock`)
    clock = 0.0 if np.any(needs_time(params)) else None
    scheme.ensure_compiled(timed=clock is not None)
    arguments = (
        state0,
        params,
        options,
        float(h),
        n_steps,
        every,
        float(drift_bound),
        samples,
        results,
        HALT_FLAG,
        clock,
    )
    # kernels chosen by an option (`rbstudy.numerics.entry.make_entry`'s switch) compile before the clock too
    prepare = getattr(scheme.run_bodies_inplace, "prepare", None)
    if prepare is not None:
        prepare(arguments)
    # a vectorised scheme (`rbstudy.numerics.batch_driver`) takes the batch in one call
    whole = getattr(scheme.run_bodies_inplace, "whole_batch", False)
    # imported here: the block path is built on this module's lanes
    from rbstudy.numerics.block import BLOCK

    align = BLOCK if getattr(scheme.run_bodies_inplace, "has_block", False) else 2
    chunks = [(0, n_bodies)] if whole else _chunks(n_bodies, threads or default_threads(), align)

    def run_chunk(rows):
        # CPU time of this thread: compute only, whatever the wait for the GIL around the call.
        begin = time.thread_time()
        scheme.run_bodies_inplace(*rows, *arguments)
        return time.thread_time() - begin

    start = time.perf_counter()
    if len(chunks) == 1:
        cpu = run_chunk(chunks[0])
    else:
        with ThreadPoolExecutor(max_workers=threads or default_threads()) as pool:
            cpu = sum(pool.map(run_chunk, chunks))
    seconds = time.perf_counter() - start
    if HALT_FLAG[0]:
        raise Halted(f"a batch of {scheme.name} was halted")
    named = {}
    for name, dtype in S.RESULT_FIELDS:
        column = results[:, Result[name]]
        if np.dtype(dtype).kind == "i" and np.isnan(column).any():
            # NaN cast to an integer is garbage (to int8 it is 0, "ok"): a scheme that does
            # not fill a result is a bug, never a number
            raise RuntimeError(f"scheme {scheme.name!r} left the result {name!r} unset")
        named[name] = column.astype(dtype)
    return BatchOutput(samples=samples, results=named, kernel_seconds=seconds, kernel_cpu_seconds=cpu)
