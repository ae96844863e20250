"""The driver of a vectorised scheme: one numpy step advances every running body of a batch.

The second kind of scheme a plug-in may bring (docs/extending.md): no compiled kernel, but a
Python function over arrays,

    init(y, p, opt, t, h, work) -> status (n,)
    step(y, p, opt, t, h, work) -> (status (n,), iterations (n,))

with ``y`` the state rows (n, N_STATE) of the n bodies still running, updated in place,
``p`` their parameter rows (n, W >= N_PARAM), ``opt`` their options (n, N_OPTION), ``t``
the time at the start of the step (s; None in a batch without loads tabulated in time, as
for the compiled kernels), ``h`` the step (s) and ``work`` their scratch and carry
(n, n_work), also updated in place. Statuses are `rbstudy.numerics.state`'s codes; a scalar
iteration count applies to every body. It is slower than a kernel, but wraps foreign code
(an engine's batch rollout, a prototype) in the studies of the built-in schemes.

`BatchStepEntry` gives it the entry point of `rbstudy.numerics.driver`'s contract, with the
same bookkeeping, written with numpy over the bodies: the samples, the blow-up test (a
non-finite state, or an energy or |L| drift past ``drift_bound`` while no moment acts), the
status and failure time, the step and iteration counts, the largest drifts and step angle.
A body's numbers are what the compiled driver would give for the same step arithmetic
(tests/test_plugins.py runs `euler` both ways, blow-ups included), and do not depend on the
other bodies of its batch: a stopped body leaves the arrays handed to the step.
"""

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.clock import step_time
from rbstudy.numerics.driver import check_statuses
from rbstudy.numerics.dynamics import body_moment, is_moment_free, space_force
from rbstudy.numerics.jit import jit
from rbstudy.numerics.lanes import HALT_CHECK_STEPS
from rbstudy.numerics.rotation import read3, read4, write3
from rbstudy.numerics.state import OK, UNSTABLE, Result

__all__ = ["BatchStepEntry", "make_batch_entry", "batch_loads"]


def _invariants(y, p):
    """Rotational energy and |L| (n,) of the state rows ``y`` by `algebra`'s formulas."""
    w = y[:, S.OMEGA : S.OMEGA + 3].T
    inertia = p[:, S.INERTIA : S.INERTIA + 3].T
    return algebra.rotational_energy(w, inertia), np.sqrt(algebra.momentum_squared(w, inertia))


def _drift(value, initial):
    """`algebra.relative_drift` over arrays: relative, or absolute where ``initial`` is 0
    (dividing by 1.0 is exact, so the numbers are the compiled driver's)."""
    return np.abs(value - initial) / np.where(initial > 0.0, initial, 1.0)


def _spin_squared(w):
    """``|w|^2`` (n,) of the rows ``w`` (n, 3), summed in the compiled driver's order (numpy's
    einsum rounds otherwise in a quarter of the rows)."""
    return w[:, 0] * w[:, 0] + w[:, 1] * w[:, 1] + w[:, 2] * w[:, 2]


def _as_counts(value, n, dtype):
    """A kernel's per-body answer (a scalar or (n,)) as an (n,) array."""
    return np.broadcast_to(np.asarray(value, dtype=dtype), (n,))


def _as_statuses(value, n):
    """A kernel's statuses (a scalar or (n,)) as an (n,) array, refused (`StatusError`)
    before the cast where one is not a status code."""
    check_statuses(value)
    return _as_counts(value, n, np.int64)


class BatchStepEntry:
    """The entry point ``run_bodies_inplace(start, stop, state0, params, options, h, n_steps,
    every, drift_bound, samples, results, halt, clock)`` of a vectorised scheme (see the
    module docstring): rows [start, stop) of a batch, all at once.

    ``whole_batch``: `rbstudy.numerics.driver.run_batch` hands it every row in one call
    (numpy's per-call overhead is what a vectorised step amortises, and the step holds the
    GIL, so threads would not share it out)."""

    whole_batch = True

    def __init__(
        self, step: Callable[..., Any], init: Callable[..., Any] | None = None, n_work: int = 0
    ) -> None:
        self.step, self.init, self.n_work = step, init, int(n_work)

    def is_cached(self, timed: bool = False) -> bool:
        """Nothing to compile: always ready (`rbstudy.schemes.Scheme.is_cached`).

        Parameters
        ----------
        timed : bool
            The variant asked for (either is ready).

        Returns
        -------
        bool
            True.
        """
        return True

    # a body that blows up overflows on its way to the status check, which records it: a
    # result, as in the compiled driver, not numpy's warning on the user's terminal
    @np.errstate(over="ignore", invalid="ignore")
    def __call__(
        self,
        start: int,
        stop: int,
        state0: np.ndarray,
        params: np.ndarray,
        options: np.ndarray,
        h: float,
        n_steps: int,
        every: int,
        drift_bound: float,
        samples: np.ndarray,
        results: np.ndarray,
        halt: np.ndarray,
        clock: float | None = None,
    ) -> None:
        rows = slice(start, stop)
        y = state0[rows].copy()
        p, opt = params[rows], options[rows]
        n = y.shape[0]
        work = np.zeros((n, self.n_work))
        energy0, momentum0 = _invariants(y, p)
        checked = np.array([is_moment_free(row) for row in p], dtype=bool)
        samples[rows, 0] = y
        largest_spin = _spin_squared(y[:, S.OMEGA : S.OMEGA + 3])  # before init, as compiled
        status = np.full(n, OK, dtype=np.int64)
        if self.init is not None:
            status[:] = _as_statuses(self.init(y, p, opt, step_time(0, h, clock), h, work), n)
        steps_done = np.zeros(n, dtype=np.int64)
        iterations = np.zeros(n, dtype=np.int64)
        max_energy, max_momentum = np.zeros(n), np.zeros(n)
        next_sample = np.ones(n, dtype=np.int64)
        for k in range(n_steps):
            running = np.flatnonzero(status == OK)
            if running.size == 0 or (k % HALT_CHECK_STEPS == 0 and halt[0] != 0):
                break
            due = (k + 1) % every == 0
            t = step_time(k, h, clock)
            if running.size == n:  # all running: the step works on the batch's own arrays
                code, iters = self.step(y, p, opt, t, h, work)
            else:
                y_run, work_run = y[running], work[running]
                code, iters = self.step(y_run, p[running], opt[running], t, h, work_run)
                y[running], work[running] = y_run, work_run
            code = _as_statuses(code, running.size).copy()
            iterations[running] += _as_counts(iters, running.size, np.int64)
            steps_done[running] += 1
            y_new = y if running.size == n else y[running]
            code[(code == OK) & ~np.isfinite(y_new.sum(axis=1))] = UNSTABLE
            energy, momentum = _invariants(y_new, p[running])
            watch = (code == OK) & checked[running]
            d_energy = _drift(energy, energy0[running])
            d_momentum = _drift(momentum, momentum0[running])
            watched = running[watch]
            max_energy[watched] = np.maximum(max_energy[watched], d_energy[watch])
            max_momentum[watched] = np.maximum(max_momentum[watched], d_momentum[watch])
            # written so that NaN drifts fail too
            code[watch & ~((d_energy <= drift_bound) & (d_momentum <= drift_bound))] = UNSTABLE
            accepted = running[code == OK]
            largest_spin[accepted] = np.maximum(
                largest_spin[accepted], _spin_squared(y[accepted, S.OMEGA : S.OMEGA + 3])
            )
            if due:
                samples[start + accepted, next_sample[accepted]] = y[accepted]
                next_sample[accepted] += 1
            status[running] = code
        for body in range(n):  # NaN after each body's last sample
            samples[start + body, next_sample[body] :] = np.nan
        tallies = _Tallies(status, steps_done, iterations, checked, max_energy, max_momentum, largest_spin)
        for name, column in _result_columns(tallies, h).items():
            results[rows, Result[name]] = column


class _Tallies(NamedTuple):
    """What the loop of `BatchStepEntry` books per body (n,): its status, steps taken, Newton
    iterations, whether its invariants are watched, its largest energy and |L| drifts, and its
    largest |w|^2."""

    status: np.ndarray
    steps_done: np.ndarray
    iterations: np.ndarray
    checked: np.ndarray
    max_energy: np.ndarray
    max_momentum: np.ndarray
    largest_spin: np.ndarray


def _result_columns(tallies, h):
    """The results of the bodies by name (`rbstudy.numerics.state.RESULT_FIELDS`), each (n,),
    as the compiled driver fills them."""
    failed = tallies.status != OK
    step_angle = h * np.sqrt(tallies.largest_spin)
    columns = {
        "status": tallies.status,
        "failure_time": np.where(failed, tallies.steps_done * h, np.nan),
        "n_steps": tallies.steps_done,
        "iterations": tallies.iterations,
        "max_energy_error": np.where(tallies.checked, tallies.max_energy, np.nan),
        "max_momentum_magnitude_error": np.where(tallies.checked, tallies.max_momentum, np.nan),
        "max_step_angle": step_angle,
        "radioss_dt_limit": step_angle > S.RADIOSS_STEP_ANGLE,
    }
    # a result added there must be computed here
    return {name: columns[name] for name, _ in S.RESULT_FIELDS}


@jit
def _loads_of_rows(y, p, t, force, moment):
    for b in range(y.shape[0]):
        q = read4(y[b], S.QUATERNION)
        write3(force[b], 0, space_force(q, p[b], t))
        write3(moment[b], 0, body_moment(q, read3(y[b], S.OMEGA), p[b], t))


def batch_loads(y: np.ndarray, p: np.ndarray, t: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The loads on a batch's bodies, by the compiled kernels of the built-in schemes, so that a
    vectorised scheme meets every load a scene can carry.

    Parameters
    ----------
    y : ndarray, shape (n, N_STATE)
        State rows.
    p : ndarray, shape (n, W)
        Parameter rows, W >= N_PARAM.
    t : float or None
        Time (s); None in a batch without loads tabulated in time.

    Returns
    -------
    force : ndarray, shape (n, 3)
        Total force in space (N).
    moment : ndarray, shape (n, 3)
        Total moment in the body frame (N m).
    """
    force, moment = np.empty((y.shape[0], 3)), np.empty((y.shape[0], 3))
    _loads_of_rows(y, p, t, force, moment)
    return force, moment


def make_batch_entry(
    step: Callable[..., Any], init: Callable[..., Any] | None = None, n_work: int = 0
) -> BatchStepEntry:
    """The entry point of a vectorised scheme (module docstring).

    Parameters
    ----------
    step : callable ``(y, p, opt, t, h, work) -> (status, iterations)``
        The step over arrays of bodies: ``y`` (n, N_STATE) updated in place, ``p`` (n, W),
        ``opt`` (n, N_OPTION), ``work`` (n, n_work); status and iterations scalars or (n,).
    init : callable ``(y, p, opt, t, h, work) -> status``, or None
        Its start (None: nothing to start).
    n_work : int
        Floats of carry per body.

    Returns
    -------
    BatchStepEntry
    """
    return BatchStepEntry(step, init, n_work)
