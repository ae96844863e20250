"""Run scenes through a scheme: scenes -> batch arrays -> driver -> named results.

This is the physics layer's bridge to the numerics: it checks that the time step divides the
output interval and the duration, packs one state row and one parameter row per scene, and
unpacks the sampled states into named arrays.
"""

from dataclasses import dataclass

import numpy as np

from rbstudy import state as S
from rbstudy.driver import DRIFT_BOUND, STATUS_NAMES, run_batch
from rbstudy.errors import RbstudyError
from rbstudy.schemes import get_scheme

__all__ = ["Simulation", "simulate", "steps_per", "STEP_RTOL"]

# A time step "divides" an interval when the quotient is within this relative distance of an
# integer: decimal inputs such as 0.01 and 2.0 are not exact binary fractions.
STEP_RTOL = 1e-9


def steps_per(interval, dt, what="interval"):
    """The whole number of steps ``dt`` in ``interval``; `RbstudyError` if there is none."""
    ratio = interval / dt
    count = round(ratio)
    if count < 1 or abs(ratio - count) > STEP_RTOL * ratio:
        raise RbstudyError(
            f"dt = {dt:g} s does not divide the {what} {interval:g} s "
            f"({interval:g} / {dt:g} = {ratio:.6g}); choose dt = {interval:g} / n")
    return int(count)


@dataclass(frozen=True)
class Simulation:
    """Results of B scenes integrated by one scheme, sampled at T times.

    time : (T,) s.  quaternion : (B, T, 4).  omega_body : (B, T, 3) rad/s.
    position, velocity : (B, T, 3) m, m/s.  status : (B,) int8 (see `status_names`).
    failure_time : (B,) s, NaN where none.  n_steps, iterations : (B,).
    max_energy_drift, max_momentum_drift : (B,) over every step, NaN under moments.
    kernel_seconds : wall time of the batch kernel (compilation excluded).
    kernel_cpu_seconds : CPU time spent in the batch kernel, summed over its threads.
    """

    scheme: str
    dt: float
    time: np.ndarray
    quaternion: np.ndarray
    omega_body: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    status: np.ndarray
    failure_time: np.ndarray
    n_steps: np.ndarray
    iterations: np.ndarray
    max_energy_drift: np.ndarray
    max_momentum_drift: np.ndarray
    kernel_seconds: float
    kernel_cpu_seconds: float

    @property
    def status_names(self):
        return [STATUS_NAMES[code] for code in self.status]


def simulate(scenes, scheme, dt, output_interval=None, options=None, drift_bound=DRIFT_BOUND,
             threads=None):
    """Integrate ``scenes`` (all of the same duration) with ``scheme`` at step ``dt``.

    Parameters
    ----------
    scenes : sequence of `rbstudy.scenes.Scene`, one per body of the batch.
    scheme : registered scheme name.
    dt : time step (s); output_interval : sampling interval (s), default ``dt``.
    options : scheme options, one mapping for all scenes or a sequence of one per scene.
    drift_bound : relative energy/|L| drift flagged as a blow-up.
    threads : threads to spread the bodies over (default: all cores).
    """
    scenes = list(scenes)
    durations = {scene.duration for scene in scenes}
    if len(durations) != 1:
        raise RbstudyError(f"a batch needs one duration, got {sorted(durations)}")
    duration = durations.pop()
    output_interval = dt if output_interval is None else output_interval
    every = steps_per(output_interval, dt, "output interval")
    n_steps = steps_per(duration, output_interval, "duration") * every
    chosen = get_scheme(scheme)
    if options is None or isinstance(options, dict):
        rows = np.repeat(chosen.option_row(options)[None, :], len(scenes), axis=0)
    else:
        rows = np.array([chosen.option_row(o) for o in options])
    out = run_batch(chosen, np.array([s.state_row() for s in scenes]),
                    np.array([s.param_row() for s in scenes]), rows, dt, n_steps, every,
                    drift_bound, threads=threads)
    samples = out.samples
    n_times = samples.shape[1]
    return Simulation(
        scheme=scheme,
        dt=dt,
        time=np.arange(n_times) * (every * dt),
        quaternion=samples[:, :, S.QUATERNION:S.QUATERNION + 4],
        omega_body=samples[:, :, S.OMEGA:S.OMEGA + 3],
        position=samples[:, :, S.POSITION:S.POSITION + 3],
        velocity=samples[:, :, S.VELOCITY:S.VELOCITY + 3],
        status=out.status,
        failure_time=out.failure_time,
        n_steps=out.n_steps,
        iterations=out.iterations,
        max_energy_drift=out.max_energy_drift,
        max_momentum_drift=out.max_momentum_drift,
        kernel_seconds=out.kernel_seconds,
        kernel_cpu_seconds=out.kernel_cpu_seconds,
    )
