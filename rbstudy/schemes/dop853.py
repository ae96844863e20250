"""`dop853`: scipy's adaptive Dormand-Prince 8(5,3) at tight tolerance: the reference peer.

Integrates the same ODE as `rk4` (``dx/dt = v``, ``dq/dt = 1/2 q * (w, 0)``,
``dv/dt = F/mass``, ``dw/dt = I^-1 (M_b - w x I w)``) with ``rtol = atol = 1e-13``, one case
after another (it is not compiled and not batched), reading the output grid from the dense
output; the quaternion is normalised at the samples. ``dt`` only sets the output grid here:
the steps are chosen by the error control, and ``n_steps`` reports the accepted steps and
``iterations`` the right-hand-side evaluations.

Order 8, explicit, adaptive. Keeps no invariant exactly, but its errors sit near 1e-12, which
is why rbstudy uses it as the reference where no closed form exists (docs/theory.md).
This is the one scheme of the numerics layer that imports scipy; it does no I/O.
Reference: Hairer, Norsett & Wanner, Solving ODEs I (1993), II.10; scipy.integrate.solve_ivp.
"""


import numpy as np
from scipy.integrate import solve_ivp

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.dynamics import is_moment_free
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import read3, read4, write3, write4
from rbstudy.numerics.state import OK, UNSTABLE, Result
from rbstudy.schemes._registry import Scheme
from rbstudy.schemes.rk4 import rates

# Tight enough that the reference error (~1e-12) sits below every compiled scheme's error at
# the time steps studied; scipy itself floors rtol near 100 eps = 2.2e-14.
RTOL = ATOL = 1e-13


@jit
def derivative(t, y, p):
    """Right-hand side for solve_ivp: ``dy/dt`` of a state row ``y`` (N_STATE,)."""
    dx, dq, dv, dw = rates(read4(y, S.QUATERNION), read3(y, S.VELOCITY), read3(y, S.OMEGA), p)
    out = np.empty(S.N_STATE)
    write3(out, S.POSITION, dx)
    write4(out, S.QUATERNION, dq)
    write3(out, S.VELOCITY, dv)
    write3(out, S.OMEGA, dw)
    return out


def _drifts(samples, p):
    """Relative drifts (T,) of the rotational energy and of |L| at each sample (T, N_STATE)
    of the parameter row ``p`` (N_PARAM,), by the formulas the compiled driver uses."""
    inertia_ = p[S.INERTIA:S.INERTIA + 3]
    w = samples[:, S.OMEGA:S.OMEGA + 3].T  # components first, as `algebra` takes them
    energy = algebra.rotational_energy(w, inertia_)
    momentum = np.sqrt(algebra.momentum_squared(w, inertia_))
    with np.errstate(invalid="ignore"):
        return (algebra.relative_drift(energy, energy[0]),
                algebra.relative_drift(momentum, momentum[0]))


def run_bodies_inplace(start, stop, state0, params, options, h, n_steps, every, drift_bound,
                       samples, results):
    """Same contract as the compiled entry points (see `rbstudy.numerics.driver`), one case at
    a time; a sample whose energy or |L| drift passes ``drift_bound`` (a moment-free body)
    counts as the failure. Results are written by name: a result added to
    `rbstudy.numerics.state.RESULT_FIELDS` must be added here too (`run_batch` refuses an
    integer result left unset)."""
    n_times = samples.shape[1]
    times = h * every * np.arange(n_times)
    for b in range(start, stop):
        p = params[b]
        solution = solve_ivp(derivative, (0.0, h * n_steps), state0[b], method="DOP853",
                             rtol=RTOL, atol=ATOL, dense_output=True, args=(p,))
        reached = solution.t[-1]
        valid = times <= reached
        out = np.full((n_times, S.N_STATE), np.nan)
        out[valid] = solution.sol(times[valid]).T if valid.any() else out[valid]
        out[valid, S.QUATERNION:S.QUATERNION + 4] /= np.linalg.norm(
            out[valid, S.QUATERNION:S.QUATERNION + 4], axis=1)[:, None]
        status = OK if solution.success and np.all(np.isfinite(out)) else UNSTABLE
        failure = np.nan if status == OK else reached
        max_energy = max_momentum = np.nan
        if is_moment_free(p):
            energy, momentum = _drifts(out, p)
            max_energy, max_momentum = float(np.nanmax(energy)), float(np.nanmax(momentum))
            bad = np.flatnonzero(~((energy <= drift_bound) & (momentum <= drift_bound)))
            if bad.size:
                status, failure = UNSTABLE, float(times[bad[0]])
                out[bad[0]:] = np.nan
        samples[b] = out
        row = {"status": status, "failure_time": failure, "n_steps": len(solution.t) - 1,
               "iterations": solution.nfev, "max_energy_error": max_energy,
               "max_momentum_magnitude_error": max_momentum}
        for name, value in row.items():
            results[b, Result[name]] = value


SCHEME = Scheme(
    name="dop853",
    summary="scipy DOP853 at rtol = atol = 1e-13, case by case: the reference peer",
    order=8,
    implicit=False,
    keeps=(),
    adaptive=True,
    run_bodies_inplace=run_bodies_inplace,
    reference="Hairer, Norsett & Wanner, Solving ODEs I (1993); scipy.integrate.solve_ivp",
)
