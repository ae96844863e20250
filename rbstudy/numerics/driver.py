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

`integrate_body_inplace` below runs one body through all its steps and `run_rows` a range of
batch rows; `make_entry` gives a scheme its entry point, a cached function that calls
`run_rows` with the scheme's kernels (`rbstudy.numerics.entry`); `run_batch` spreads chunks of
rows over threads (the kernels release the GIL). numba inlines `run_rows` and
`integrate_body_inplace` into each entry point (`inline_jit`): the kernels are then never
passed as values, which numba could not cache. The loop writes element by element and
allocates nothing; `run_rows` allocates each body's arrays.
Threads rather than numba's `prange` keep the kernels safe to call from several dask worker
threads at once and let the caller choose the number of cores.

A run can be halted from outside: `request_halt` sets a flag that every body's loop reads
every `HALT_CHECK_STEPS` steps (a few milliseconds of work at most), so that Ctrl-C ends even
a batch of 1e12 steps at once; `run_batch` then raises `Halted` instead of returning partial
numbers. The flag is an array the compiled loops read from memory, not a constant they could
keep in a register.

Failure is data, never an exception: a body whose state turns non-finite, or whose energy or
angular momentum drifts past ``drift_bound`` while no moment acts, stops with status
``UNSTABLE`` and its failure time; an implicit step whose Newton iteration does not converge
stops with ``NOT_CONVERGED``. Its later samples are NaN. Other bodies are unaffected, and a
body's numbers do not depend on which batch it ran in (no cross-body operations).
"""

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.clock import step_time
from rbstudy.numerics.dynamics import is_moment_free, momentum_squared, rotational_energy
from rbstudy.numerics.entry import CachedEntry
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.machine import default_threads
from rbstudy.numerics.rotation import dot, read3
from rbstudy.numerics.state import OK, UNSTABLE, Result

__all__ = [
    "DRIFT_BOUND", "BatchOutput", "init_nothing", "integrate_body_inplace", "run_rows",
    "make_entry",
    "run_batch", "n_samples", "Halted", "request_halt", "clear_halt",
    "HALT_CHECK_STEPS", "HALT_FLAG",
]

# Relative drift of the rotational energy or of |L| beyond which a moment-free body counts as
# blown up. Half its size is far outside any accurate run (accurate runs sit below 1e-2) and
# well before overflow, so a diverging explicit scheme is stopped while its numbers are finite.
DRIFT_BOUND = 0.5

# Chunks of rows handed to each thread of `run_batch`.
_CHUNKS_PER_THREAD = 4

# Steps between two reads of the halt flag (a power of two: the test is a mask).
HALT_CHECK_STEPS = 1024
_HALT_MASK = HALT_CHECK_STEPS - 1
# The halt flag of this process: nonzero once `request_halt` is called.
HALT_FLAG = np.zeros(1, dtype=np.int64)


class Halted(Exception):
    """A batch stopped by `request_halt` before its end: it has no results."""


def request_halt():
    """Make every running and later batch of this process stop within `HALT_CHECK_STEPS`
    steps and raise `Halted` (Ctrl-C)."""
    HALT_FLAG[0] = 1


def clear_halt():
    """Let batches run again (a new sweep in the same process)."""
    HALT_FLAG[0] = 0


def n_samples(n_steps, every):
    """Number of output samples (including t = 0) of a run of ``n_steps`` sampled every ``every``."""
    return n_steps // every + 1


@jit
def init_nothing(y, p, opt, t, h, work):
    """The ``init_inplace`` of schemes that carry nothing between steps."""
    return OK


_relative_drift = jit(algebra.relative_drift)


@inline_jit
def integrate_body_inplace(step, init, b, y, work, params, options, h, n_steps, every,
                           drift_bound, samples, results, halt, clock):
    """Integrate body ``b`` of a batch from state ``y``; write its samples and results.

    Parameters
    ----------
    step, init : compiled kernels of one scheme (see module docstring).
    b : int, the body's row in the batch arrays.
    y : (N_STATE,) the body's initial state, a fresh array owned by this call (mutated).
    work : (n_work,) zeroed work array of the scheme (mutated).
    params : (B, W) parameters, W >= N_PARAM (`rbstudy.numerics.state.row_width`);
    options : (B, N_OPTION) scheme options (read only).
    h : float, time step (s); n_steps : int; every : int, steps between samples.
    drift_bound : float, relative energy / |L| drift that flags a moment-free body unstable.
    samples : (B, T, N_STATE) output, T = n_steps // every + 1; row b is written.
    results : (B, N_RESULT) output, row b written by name (`rbstudy.numerics.state`): the
        drifts are NaN under moments, the failure time NaN when the body finished; the
        largest step angle dt |w| and the Radioss flag cover every step taken.
    halt : (1,) int64, the halt flag: the body stops early when it is nonzero (its numbers
        are then discarded by `run_batch`).
    clock : 0.0 to give the kernels the time, None to compile them without it
        (`rbstudy.numerics.clock`).
    """
    p = params[b]
    opt = options[b]
    inertia_ = read3(p, S.INERTIA)
    w0 = read3(y, S.OMEGA)
    energy0 = rotational_energy(w0, inertia_)
    momentum0 = math.sqrt(momentum_squared(w0, inertia_))
    check_invariants = is_moment_free(p)
    largest_spin = dot(w0, w0)  # the largest |w|^2, for the Radioss check

    for k in range(S.N_STATE):
        samples[b, 0, k] = y[k]
    status = init(y, p, opt, step_time(0, h, clock), h, work)
    iterations = 0
    steps_done = 0
    max_energy = 0.0
    max_momentum = 0.0
    sample = 1
    while status == OK and steps_done < n_steps:
        if (steps_done & _HALT_MASK) == 0 and halt[0] != 0:
            break
        status, iters = step(y, p, opt, step_time(steps_done, h, clock), h, work)
        iterations += iters
        steps_done += 1
        total = 0.0
        for k in range(S.N_STATE):
            total += y[k]
        if status == OK and not math.isfinite(total):
            status = UNSTABLE
        if status == OK and check_invariants:
            w = read3(y, S.OMEGA)
            d_energy = _relative_drift(rotational_energy(w, inertia_), energy0)
            d_momentum = _relative_drift(math.sqrt(momentum_squared(w, inertia_)), momentum0)
            max_energy = max(max_energy, d_energy)
            max_momentum = max(max_momentum, d_momentum)
            # written so that NaN drifts also fail the test
            if not (d_energy <= drift_bound and d_momentum <= drift_bound):
                status = UNSTABLE
        if status == OK:  # the spin of accepted states only: a blow-up flags nothing
            spin = dot(read3(y, S.OMEGA), read3(y, S.OMEGA))
            if spin > largest_spin:
                largest_spin = spin
        if status == OK and steps_done % every == 0:
            for k in range(S.N_STATE):
                samples[b, sample, k] = y[k]
            sample += 1

    for t in range(sample, samples.shape[1]):
        for k in range(S.N_STATE):
            samples[b, t, k] = math.nan
    results[b, Result.status] = status
    results[b, Result.failure_time] = steps_done * h if status != OK else math.nan
    results[b, Result.n_steps] = steps_done
    results[b, Result.iterations] = iterations
    results[b, Result.max_energy_error] = max_energy if check_invariants else math.nan
    results[b, Result.max_momentum_magnitude_error] = max_momentum if check_invariants else math.nan
    step_angle = h * math.sqrt(largest_spin)
    results[b, Result.max_step_angle] = step_angle
    results[b, Result.radioss_dt_limit] = step_angle > S.RADIOSS_STEP_ANGLE


@inline_jit
def run_rows(step, init, n_work, start, stop, state0, params, options, h, n_steps, every,
             drift_bound, samples, results, halt, clock):
    """Integrate the rows [start, stop) of a batch with a scheme's kernels ``step`` and
    ``init`` and ``n_work`` floats of work per body (`integrate_body_inplace`)."""
    for b in range(start, stop):
        if halt[0] != 0:
            return
        integrate_body_inplace(step, init, b, state0[b].copy(), np.zeros(n_work), params,
                               options, h, n_steps, every, drift_bound, samples, results,
                               halt, clock)


def make_entry(step, init, n_work, wrapper=None):
    """The entry point of a scheme: ``run_bodies_inplace(start, stop, state0, params,
    options, h, n_steps, every, drift_bound, samples, results, halt, clock)`` integrates rows
    [start, stop) (`run_rows`) with the kernel ``step``, or with ``wrapper(step, ...)`` when
    given (an inlined kernel that takes the step first: a composition); numba compiles it, or
    loads it from its cache, for each type of ``clock`` (None or a float) when first called
    with it (`rbstudy.numerics.entry`)."""
    return CachedEntry(step, init, n_work, wrapper)


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


def _as_rows(array, width, name, wider=False):
    """``array`` as C-ordered float rows (B, width), or at least ``width`` wide."""
    rows = np.ascontiguousarray(array, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] < width or (rows.shape[1] != width and not wider):
        raise ValueError(f"`{name}` must have shape (B, {width}{' or more' if wider else ''}), "
                         f"got {rows.shape}")
    return rows


def _check_knots(params):
    """Refuse parameter rows too narrow for the knots they announce (`S.KNOTS`)."""
    knots = params[:, S.KNOTS]
    if np.any((knots < 0) | (knots != np.round(knots))):
        raise ValueError(f"`params` announce knot counts {sorted(set(knots.tolist()))}: "
                         "each must be a whole number >= 0")
    if np.any(S.row_width(knots) > params.shape[1]):
        raise ValueError(f"`params` rows of width {params.shape[1]} cannot hold the "
                         f"{int(knots.max())} knots they announce")


def _chunks(n_bodies, threads):
    """Contiguous row ranges: a few per thread, so that early blow-ups do not idle a core."""
    pieces = min(n_bodies, threads * _CHUNKS_PER_THREAD) if threads > 1 else 1
    edges = np.linspace(0, n_bodies, pieces + 1).astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def run_batch(scheme, state0, params, options, h, n_steps, every, drift_bound=DRIFT_BOUND,
              threads=None):
    """Run a batch with a registered scheme and return a `BatchOutput`.

    Parameters
    ----------
    scheme : `rbstudy.schemes.Scheme`.
    state0 : (B, N_STATE); params : (B, W >= N_PARAM); options : (B, N_OPTION).
    h : float, time step (s); n_steps : int >= 0; every : int >= 1, steps per sample.
    drift_bound : float, see `DRIFT_BOUND`.
    threads : int, threads to spread the bodies over (default: all cores; 1 under a
        scheduler that already runs one task per core).

    The first call of a scheme in a process compiles (or loads from cache) before the clock
    starts, so ``kernel_seconds`` is run time only. Raises `Halted` when `request_halt` was
    called before the batch ended.
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
    # the kernels take the time only where some body has loads tabulated in time: a batch of
    # constant loads runs kernels compiled without it (`rbstudy.numerics.clock`)
    clock = 0.0 if np.any(params[:, S.KNOTS] != 0.0) else None
    scheme.ensure_compiled(timed=clock is not None)
    arguments = (state0, params, options, float(h), n_steps, every, float(drift_bound), samples,
                 results, HALT_FLAG, clock)
    chunks = _chunks(n_bodies, threads or default_threads())

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
    return BatchOutput(samples=samples, results=named, kernel_seconds=seconds,
                       kernel_cpu_seconds=cpu)
