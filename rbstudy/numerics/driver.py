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

`rbstudy.numerics.rows` steps the bodies of a range of batch rows through all their steps
with a scheme's kernels; `rbstudy.numerics.entry.make_entry` gives a scheme its entry point, a
cached function that calls it with the scheme's kernels; `run_batch` spreads chunks of rows
over threads (the kernels release the GIL). Threads rather than numba's `prange` keep the
kernels safe to call from several dask worker threads at once and let the caller choose the
number of cores.

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
from rbstudy.numerics.block import BLOCK
from rbstudy.numerics.jit import jit
from rbstudy.numerics.loads import needs_time
from rbstudy.numerics.machine import default_threads
from rbstudy.numerics.state import OK, Result

__all__ = [
    "DRIFT_BOUND",
    "BatchOutput",
    "init_nothing",
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


def check_statuses(codes: object) -> None:
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
    # integers, the usual answer, in two reductions: np.isin is several times slower, and a
    # vectorised scheme checks every step
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


def request_halt() -> None:
    """Make every running and later batch of this process stop within `HALT_CHECK_STEPS`
    steps and raise `Halted` (Ctrl-C)."""
    HALT_FLAG[0] = 1


def clear_halt() -> None:
    """Let batches run again (a new sweep in the same process)."""
    HALT_FLAG[0] = 0


def n_samples(n_steps: int, every: int) -> int:
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

    # read-only, as a `rbstudy.schemes.Scheme` (frozen) has them
    @property
    def name(self) -> str: ...

    @property
    def run_bodies_inplace(self) -> Callable: ...

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


def _checked_batch(state0, params, options, n_steps, every):
    """The batch's initial states, parameter rows and option rows as C-ordered float rows of
    their widths, checked to be as many, and its steps and steps per sample as checked ints."""
    state0 = _as_rows(state0, S.N_STATE, "state0")
    params = _as_rows(params, S.N_PARAM, "params", wider=True)
    _check_knots(params)
    options = _as_rows(options, S.N_OPTION, "options")
    if not (state0.shape[0] == params.shape[0] == options.shape[0]):
        raise ValueError("`state0`, `params` and `options` must have the same number of rows")
    n_steps, every = int(n_steps), int(every)
    if n_steps < 0 or every < 1:
        raise ValueError(f"need n_steps >= 0 and every >= 1, got {n_steps}, {every}")
    return state0, params, options, n_steps, every


def _named_results(scheme_name, results):
    """The results (B, N_RESULT) by name, each (B,) of its storage type."""
    named = {}
    for name, dtype in S.RESULT_FIELDS:
        column = results[:, Result[name]]
        if np.dtype(dtype).kind == "i" and np.isnan(column).any():
            # NaN cast to an integer is garbage (to int8 it is 0, "ok"): a scheme that does
            # not fill a result is a bug, never a number
            raise RuntimeError(f"scheme {scheme_name!r} left the result {name!r} unset")
        named[name] = column.astype(dtype)
    return named


def _chunks_for(entry, n_bodies, threads):
    """The chunks of rows a scheme's entry point is called with: the whole batch for a
    vectorised scheme (`rbstudy.numerics.batch_driver`), else a few per thread, whole blocks
    for a scheme that steps blocks."""
    if getattr(entry, "whole_batch", False):
        return [(0, n_bodies)]
    return _chunks(n_bodies, threads, BLOCK if getattr(entry, "has_block", False) else 2)


def _run_chunks(entry, chunks, arguments, threads):
    """Run a scheme's entry point over the chunks of rows, on ``threads`` threads (all cores if
    None); returns the wall time (s) and the CPU time of the threads inside the calls, summed."""

    def run_chunk(rows):
        # CPU time of this thread: compute only, whatever the wait for the GIL around the call.
        begin = time.thread_time()
        entry(*rows, *arguments)
        return time.thread_time() - begin

    start = time.perf_counter()
    if len(chunks) == 1:
        cpu = run_chunk(chunks[0])
    else:
        with ThreadPoolExecutor(max_workers=threads or default_threads()) as pool:
            cpu = sum(pool.map(run_chunk, chunks))
    return time.perf_counter() - start, cpu


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
    state0, params, options, n_steps, every = _checked_batch(state0, params, options, n_steps, every)
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
    chunks = _chunks_for(scheme.run_bodies_inplace, n_bodies, threads or default_threads())
    seconds, cpu = _run_chunks(scheme.run_bodies_inplace, chunks, arguments, threads)
    if HALT_FLAG[0]:
        raise Halted(f"a batch of {scheme.name} was halted")
    named = _named_results(scheme.name, results)
    return BatchOutput(samples=samples, results=named, kernel_seconds=seconds, kernel_cpu_seconds=cpu)
