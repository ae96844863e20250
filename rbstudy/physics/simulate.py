"""Run scenes through a scheme: scenes -> batch arrays -> driver -> named results.

This is the physics layer's bridge to the numerics: it checks that the time step divides the
output interval and the duration, packs one state row and one parameter row per scene, and
names the slices of the sampled states.
"""

from dataclasses import dataclass

import numpy as np

from rbstudy.errors import InputError, RbstudyError
from rbstudy.numerics import state as S
from rbstudy.numerics.driver import DRIFT_BOUND, BatchOutput, run_batch
from rbstudy.numerics.state import STATUS_NAMES
from rbstudy.physics.scenes import param_rows
from rbstudy.schemes import get_scheme

__all__ = ["Simulation", "simulate", "steps_per", "STEP_RTOL"]

# A time step "divides" an interval when the quotient is within this relative distance of an
# integer: decimal inputs such as 0.01 and 2.0 are not exact binary fractions.
STEP_RTOL = 1e-9
# Beyond this many steps in one interval the divisibility test itself loses its meaning (the
# quotient's rounding passes STEP_RTOL) and no run could finish.
MAX_STEPS_PER_INTERVAL = 1e12


def steps_per(interval, step, step_name="dt", interval_name="interval"):
    """The whole number of ``step``s in ``interval``; an unplaced `InputError` if there is
    none (the caller knows the file and key)."""
    ratio = interval / step
    if not ratio < MAX_STEPS_PER_INTERVAL:  # inf for a subnormal step, NaN for a NaN
        raise InputError(f"{step_name} = {step:g} s is too small for the {interval_name} "
                         f"{interval:g} s (over {MAX_STEPS_PER_INTERVAL:.0e} steps)",
                         f"choose {step_name} = {interval:g} / n with a reasonable n")
    count = round(ratio)
    if count < 1 or abs(ratio - count) > STEP_RTOL * ratio:
        raise InputError(
            f"{step_name} = {step:g} s does not divide the {interval_name} {interval:g} s "
            f"({interval:g} / {step:g} = {ratio:.6g})",
            f"choose {step_name} = {interval:g} / n")
    return int(count)


@dataclass(frozen=True)
class Simulation:
    """Results of B scenes integrated by one scheme, sampled at T times.

    time : (T,) s. output : the driver's `BatchOutput` (sampled states, per-body results by
    name, kernel timings). The named slices of the states: quaternion (B, T, 4), omega_body
    (B, T, 3) rad/s, position and velocity (B, T, 3) m, m/s.
    """

    scheme: str
    dt: float
    time: np.ndarray
    output: BatchOutput

    def field(self, name):
        """The samples of the state field ``name`` (`rbstudy.numerics.state.STATE_FIELDS`)."""
        return self.output.samples[:, :, S.STATE_FIELDS[name]]

    quaternion = property(lambda self: self.field("quaternion"))
    omega_body = property(lambda self: self.field("omega_body"))
    position = property(lambda self: self.field("position"))
    velocity = property(lambda self: self.field("velocity"))

    @property
    def results(self):
        """Per-body results by name (`rbstudy.numerics.state.RESULT_FIELDS`), (B,) each."""
        return self.output.results

    @property
    def status_names(self):
        return [STATUS_NAMES[code] for code in self.results["status"]]


def simulate(scenes, scheme, dt, output_interval=None, options=None, drift_bound=DRIFT_BOUND,
             threads=None):
    """Integrate ``scenes`` (all of the same duration) with ``scheme`` at step ``dt``.

    Parameters
    ----------
    scenes : sequence of `rbstudy.physics.scenes.Scene`, one per body of the batch.
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
    every = steps_per(output_interval, dt, "dt", "output interval")
    n_steps = steps_per(duration, output_interval, "output interval", "duration") * every
    chosen = get_scheme(scheme)
    if options is None or isinstance(options, dict):
        rows = np.repeat(chosen.option_row(options)[None, :], len(scenes), axis=0)
    else:
        rows = np.array([chosen.option_row(o) for o in options])
    output = run_batch(chosen, np.array([s.state_row() for s in scenes]),
                       param_rows(scenes), rows, dt, n_steps, every,
                       drift_bound, threads=threads)
    return Simulation(scheme=scheme, dt=dt, time=np.arange(output.samples.shape[1]) * (every * dt),
                      output=output)
