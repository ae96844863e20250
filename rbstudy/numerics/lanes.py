"""A body's bookkeeping as it steps, shared by the single-body loop (`rbstudy.numerics.driver`)
and the block path (`rbstudy.numerics.block`): its first sample and invariants, each step's
verdict (a non-finite state, an energy or |L| drift past the bound while no moment acts), its
tallies, and its results at the end.

A lane is the tuple ``(status, steps_done, iterations, max_energy, max_momentum,
largest_spin, sample)`` that `lane_start` begins and `lane_after_step` carries (``largest_spin``
the largest ``|w|^2``, for the Radioss check; ``sample`` the next sample's index); the block path
keeps the same fields in rows, one lane per column, and books them with the same tests in the
same order.
"""

import math

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.dynamics import is_moment_free, momentum_squared, rotational_energy
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import dot, read3
from rbstudy.numerics.state import OK, UNSTABLE, Result

__all__ = [
    "HALT_CHECK_STEPS",
    "HALT_MASK",
    "IDLE",
    "SAMPLE",
    "relative_drift",
    "state_sum",
    "store_sample",
    "lane_start",
    "with_status",
    "lane_after_step",
    "lane_end",
]

# Steps between two reads of the halt flag (a power of two: the test is a mask).
HALT_CHECK_STEPS = 1024
HALT_MASK = HALT_CHECK_STEPS - 1

# The relative drift of an invariant (`rbstudy.numerics.algebra.relative_drift`), compiled.
relative_drift = jit(algebra.relative_drift)


# The status of a lane without a body (the second lane of a scheme of one lane, the last row of
# an odd range, a block's lanes past its batch): never OK, so it never steps, and never stored.
IDLE = -1
# Where a lane's tuple keeps its next sample's index (`lane_start`).
SAMPLE = 6


@jit
def state_sum(y):
    """The sum of a state row: finite exactly when every entry is.

    Parameters
    ----------
    y : ndarray, shape (N_STATE,)
        A body's state row.

    Returns
    -------
    float
    """
    total = 0.0
    for k in range(S.N_STATE):
        total += y[k]
    return total


@jit
def store_sample(samples, b, sample, y):
    """Write the state row ``y`` as sample ``sample`` of body ``b``.

    Parameters
    ----------
    samples : ndarray, shape (B, T, N_STATE)
        The batch's samples (written).
    b : int
        The body's row.
    sample : int
        The sample's index, 0 <= sample < T.
    y : ndarray, shape (N_STATE,)
        The body's state row.
    """
    for k in range(S.N_STATE):
        samples[b, sample, k] = y[k]


@jit
def lane_start(b, y, p, samples):
    """Start body ``b`` before its scheme's ``init``: store its first sample.

    Parameters
    ----------
    b : int
        The body's row.
    y : ndarray, shape (N_STATE,)
        Its state row at t = 0.
    p : ndarray, shape (W,)
        Its parameter row, W >= N_PARAM.
    samples : ndarray, shape (B, T, N_STATE)
        The batch's samples (sample 0 of row ``b`` written).

    Returns
    -------
    fixed : tuple of 3
        The body's invariants at t = 0 and whether they must hold, ``(energy0, momentum0,
        check_invariants)``.
    lane : tuple of 7
        ``(OK, 0, 0, 0.0, 0.0, |w0|^2, 1)``: its lane, which `lane_after_step` carries.
    """
    inertia_ = read3(p, S.INERTIA)
    w0 = read3(y, S.OMEGA)
    fixed = (rotational_energy(w0, inertia_), math.sqrt(momentum_squared(w0, inertia_)), is_moment_free(p))
    store_sample(samples, b, 0, y)
    return fixed, (OK, 0, 0, 0.0, 0.0, dot(w0, w0), 1)


@jit
def with_status(lane, status):
    """The lane with its status replaced (by that of the scheme's ``init``).

    Parameters
    ----------
    lane : tuple
        ``(status, steps_done, iterations, max_energy, max_momentum, largest_spin, sample)``
        (module docstring).
    status : int
        The new status.

    Returns
    -------
    tuple of 7
    """
    return (status,) + lane[1:]


@jit
def lane_after_step(lane, fixed, status, iters, total, w, inertia_, drift_bound, due):
    """Book a step that a lane's body has just taken. When the returned lane's status is still
    OK and the step was ``due``, the caller stores the sample before the lane's index.

    Scalars only, and a compiled function rather than an inlined one: numba gives each
    array that enters an inlined function a reference count, whose atomic updates on every
    step kept the two lanes of `rbstudy.numerics.rows.integrate_rows_inplace` from
    overlapping, and every function it inlines costs compile time.

    Parameters
    ----------
    lane : tuple
        ``(status, steps_done, iterations, max_energy, max_momentum, largest_spin, sample)``
        (module docstring).
    fixed : tuple of 3
        ``(energy0, momentum0, check_invariants)`` of `lane_start`.
    status, iters : int
        The status and Newton iterations the scheme's step returned.
    total : float
        The sum of the new state (`state_sum`): finite exactly when all of it is.
    w : tuple of 3 floats
        The new spin, rad/s, body axes.
    inertia_ : tuple of 3 floats
        The principal inertias, kg m^2.
    drift_bound : float
        The relative energy or |L| drift that makes a moment-free body unstable.
    due : bool
        Whether a sample falls on this step.

    Returns
    -------
    tuple of 7
        The lane after the step.
    """
    steps_done, iterations, max_energy, max_momentum, largest_spin, sample = lane[1:]
    energy0, momentum0, check_invariants = fixed
    iterations += iters
    steps_done += 1
    if status == OK and not math.isfinite(total):
        status = UNSTABLE
    if status == OK and check_invariants:
        d_energy = relative_drift(rotational_energy(w, inertia_), energy0)
        d_momentum = relative_drift(math.sqrt(momentum_squared(w, inertia_)), momentum0)
        max_energy = max(max_energy, d_energy)
        max_momentum = max(max_momentum, d_momentum)
        # written so that NaN drifts also fail the test
        if not (d_energy <= drift_bound and d_momentum <= drift_bound):
            status = UNSTABLE
    if status == OK:  # the spin of accepted states only: a blow-up flags nothing
        spin = dot(w, w)
        if spin > largest_spin:
            largest_spin = spin
        if due:
            sample += 1
    return (status, steps_done, iterations, max_energy, max_momentum, largest_spin, sample)


@jit
def lane_end(lane, fixed, b, h, samples, results):
    """Fill body ``b``'s samples after its last one with NaN and write its results.

    Parameters
    ----------
    lane : tuple
        ``(status, steps_done, iterations, max_energy, max_momentum, largest_spin, sample)``
        (module docstring).
    fixed : tuple of 3
        ``(energy0, momentum0, check_invariants)`` of `lane_start`.
    b : int
        The body's row.
    h : float
        The time step (s).
    samples : ndarray, shape (B, T, N_STATE)
        The batch's samples (row ``b`` written).
    results : ndarray, shape (B, N_RESULT)
        The batch's results, by name (`rbstudy.numerics.state.Result`; row ``b`` written).
    """
    status, steps_done, iterations, max_energy, max_momentum, largest_spin, sample = lane
    check_invariants = fixed[2]
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
