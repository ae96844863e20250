"""`dop853`: scipy's adaptive Dormand-Prince 8(5,3) at tight tolerance: the reference peer.

Integrates the same ODE as `rk4` (``dx/dt = v``, ``dq/dt = 1/2 q * (w, 0)``,
``dv/dt = F/mass``, ``dw/dt = I^-1 (M_b - w x I w)``) with ``rtol = atol = 1e-13``, one case
after another (it is not compiled and not batched), stepping scipy's solver itself and sampling each
step's dense output at the output times it covers (no interpolant is kept, so a run of
millions of steps needs no more memory than its samples); the quaternion is normalised at the
samples. `integrate` is the same run with an optional step budget, for the references; as a
scheme a body takes at most `MAX_STEPS` (then it is not converged).
``dt`` only sets the output grid here: the steps are chosen by the error control, and
``n_steps`` reports the accepted steps and ``iterations`` the right-hand-side evaluations
(including those of the dense output at the steps that cover a sample).

Order 8, explicit, adaptive. Keeps no invariant exactly, but its errors sit near 1e-12, which
is why rbstudy uses it as the reference where no closed form exists (docs/theory.md).
This is the one scheme of the numerics layer that imports scipy; it does no I/O.
Reference: Hairer, Norsett & Wanner, Solving ODEs I (1993), II.10; scipy.integrate.solve_ivp.
"""

from dataclasses import dataclass

import numpy as np

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.dynamics import is_moment_free
from rbstudy.numerics.entry import cache_holds
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import read3, read4, write3, write4
from rbstudy.numerics.state import NOT_CONVERGED, OK, UNSTABLE, Result
from rbstudy.schemes._registry import Scheme, Style
from rbstudy.schemes.rk4 import rates

# Tight enough that the reference error (~1e-12) sits below every compiled scheme's error at
# the time steps studied; scipy itself floors rtol near 100 eps = 2.2e-14.
RTOL = 1e-13  # and atol
# Accepted steps one body may take as a scheme: long past any forecast run of one core,
# |w0| T up to ~1.5e6 rad at the ~6.5 steps per radian it takes. A study forecast past the
# --max-body-steps budget is refused before it runs; this bounds a run the forecast could
# not see (a load that spins the body up, a budget raised past any sense): such a body
# stops as not converged.
MAX_STEPS = 10_000_000


@jit
def derivative(t, y, p):
    """Right-hand side for scipy's DOP853: ``dy/dt`` of a state row ``y`` (N_STATE,)."""
    dx, dq, dv, dw = rates(read4(y, S.QUATERNION), read3(y, S.VELOCITY), read3(y, S.OMEGA), p, t)
    out = np.empty(S.N_STATE)
    write3(out, S.POSITION, dx)
    write4(out, S.QUATERNION, dq)
    write3(out, S.VELOCITY, dv)
    write3(out, S.OMEGA, dw)
    return out


def _drifts(samples, p):
    """Relative drifts (T,) of the rotational energy and of |L| at each sample (T, N_STATE)
    of the parameter row ``p`` (at least N_PARAM wide), by the formulas the compiled driver
    uses."""
    inertia_ = p[S.INERTIA : S.INERTIA + 3]
    w = samples[:, S.OMEGA : S.OMEGA + 3].T  # components first, as `algebra` takes them
    energy = algebra.rotational_energy(w, inertia_)
    momentum = np.sqrt(algebra.momentum_squared(w, inertia_))
    with np.errstate(invalid="ignore"):
        return (algebra.relative_drift(energy, energy[0]), algebra.relative_drift(momentum, momentum[0]))


@dataclass(frozen=True)
class Trajectory:
    """One body's DOP853 run sampled at T times: ``samples`` (T, N_STATE), NaN past
    ``reached`` (s); accepted ``steps`` and right-hand-side ``evaluations``; ``finished``
    when it reached the last time (a run that stopped at ``max_steps`` first did not);
    ``max_step_angle``, the largest accepted step times |w| at its end (rad)."""

    samples: np.ndarray
    reached: float
    steps: int
    evaluations: int
    finished: bool
    max_step_angle: float


def _segment_ends(p, end):
    """Where the runs of one integration end: the knots of the loads tabulated in time inside
    (0, ``end``) (the loads have a kink there, which an 8th-order step must not straddle),
    then ``end``."""
    count = int(p[S.KNOTS])
    knots = np.asarray(p[S.N_PARAM : S.N_PARAM + count])
    return [*knots[(knots > 0.0) & (knots < end)].tolist(), float(end)]


def integrate(
    y0: np.ndarray,
    p: np.ndarray,
    times: np.ndarray,
    max_steps: int | None = None,
    halt: np.ndarray | None = None,
    tolerance: float = RTOL,
) -> Trajectory:
    """Integrate state row ``y0`` (N_STATE,) with parameters ``p`` (a parameter row) over
    ``times`` (T,), 0 first, step by step, sampling the dense output of each step that covers
    a sample time (so memory stays (T, N_STATE) however many steps a fast spin takes). The
    solver restarts at every knot of loads tabulated in time, so that no step straddles a
    kink of the loads.

    ``max_steps`` bounds the accepted steps (None: no bound); ``halt`` (a (1,) array, see
    `rbstudy.numerics.driver.request_halt`) is read every step. ``tolerance``: rtol and
    atol (the scheme's `RTOL`; a benchmark asks for less).
    """
    # here, not at the top: scipy.integrate would cost every command that loads the schemes
    # its import, and a first run's notice should come at once (issue 30)
    from scipy.integrate import DOP853

    samples = np.full((len(times), S.N_STATE), np.nan)
    samples[0] = y0
    y, start = np.array(y0, dtype=float), 0.0
    filled, steps, evaluations, max_step_angle = 1, 0, 0, 0.0
    stopped = False
    # a spin past ~1e154 rad/s squares past the float range inside scipy: the run turns
    # non-finite and is reported so (not finished), without numpy's warnings on the terminal
    with np.errstate(all="ignore"):
        for end in _segment_ends(p, float(times[-1])):
            solver = DOP853(lambda t, y: derivative(t, y, p), start, y, end, rtol=tolerance, atol=tolerance)
            while solver.status == "running" and filled < len(times):
                if (halt is not None and halt[0]) or (max_steps is not None and steps >= max_steps):
                    stopped = True
                    break
                solver.step()
                if solver.status == "failed":  # the step was rejected for good: not an accepted one
                    break
                steps += 1
                max_step_angle = max(
                    max_step_angle, solver.step_size * float(np.linalg.norm(solver.y[S.OMEGA : S.OMEGA + 3]))
                )
                covered = np.searchsorted(times, solver.t, side="right")
                if covered > filled:
                    samples[filled:covered] = solver.dense_output()(times[filled:covered]).T
                    filled = covered
            evaluations += solver.nfev
            if stopped or solver.status == "failed":
                break
            y, start = solver.y, end
    quaternions = samples[:filled, S.STATE_FIELDS["quaternion"]]
    quaternions /= np.linalg.norm(quaternions, axis=1)[:, None]
    finished = filled == len(times) and np.all(np.isfinite(samples))
    return Trajectory(samples, float(solver.t), steps, evaluations, bool(finished), max_step_angle)


def run_bodies_inplace(
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
    """Same contract as the compiled entry points (see `rbstudy.numerics.driver`), one case at
    a time (``clock`` unused: the right-hand side always takes the time); a sample whose
    energy or |L| drift passes ``drift_bound`` (a moment-free body) counts as the failure.
    Results are written by name: a result added to `rbstudy.numerics.state.RESULT_FIELDS`
    must be added here too (`run_batch` refuses an integer result left unset)."""
    times = h * every * np.arange(samples.shape[1])
    for b in range(start, stop):
        if halt[0]:
            return
        p = params[b]
        run = integrate(state0[b], p, times, max_steps=MAX_STEPS, halt=halt)
        out = run.samples
        status = OK if run.finished else NOT_CONVERGED if run.steps >= MAX_STEPS else UNSTABLE
        failure = np.nan if status == OK else run.reached
        max_energy = max_momentum = np.nan
        if is_moment_free(p):
            energy, momentum = _drifts(out, p)
            with np.errstate(invalid="ignore"):
                max_energy, max_momentum = float(np.nanmax(energy)), float(np.nanmax(momentum))
            kept = (energy <= drift_bound) & (momentum <= drift_bound)
            if status == NOT_CONVERGED:  # stopped at the cap: the samples past it are NaN
                kept |= np.isnan(energy) | np.isnan(momentum)
            bad = np.flatnonzero(~kept)
            if bad.size:
                status, failure = UNSTABLE, float(times[bad[0]])
                out[bad[0] :] = np.nan
        samples[b] = out
        row = {
            "status": status,
            "failure_time": failure,
            "n_steps": run.steps,
            "iterations": run.evaluations,
            "max_energy_error": max_energy,
            "max_momentum_magnitude_error": max_momentum,
            "max_step_angle": run.max_step_angle,
            "radioss_dt_limit": run.max_step_angle > S.RADIOSS_STEP_ANGLE,
        }
        for name, value in row.items():
            results[b, Result[name]] = value


def _is_cached(timed=False):
    """(`rbstudy.schemes.Scheme.is_cached`) Whether numba's cache holds the right-hand side,
    this scheme's one compiled kernel, which takes the time either way (and the time to compile)."""
    return cache_holds(derivative)


# the registry asks the entry point for `is_cached` (as numba's dispatchers of the compiled
# schemes carry one); mypy knows no such attribute on a plain function
run_bodies_inplace.is_cached = _is_cached  # type: ignore[attr-defined]

SCHEME = Scheme(
    name="dop853",
    summary="scipy DOP853 at rtol = atol = 1e-13, case by case: the reference peer",
    # what a step costs as the references take it, sampled every many steps (the forecast's
    # figure until `rbstudy.pipeline.calibration.reference_cost` has measured it here): between
    # the calibrated cost and what a step takes within a sweep on the 2-core machine
    step_seconds=1.5e-04,
    order=8,
    implicit=False,
    keeps=(),
    adaptive=True,
    run_bodies_inplace=run_bodies_inplace,
    reference="Hairer, Norsett & Wanner, Solving ODEs I (1993); scipy.integrate.solve_ivp",
    style=Style("black", "+", ":"),
)
