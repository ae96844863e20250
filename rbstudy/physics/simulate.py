"""Run scenes through a scheme: scenes -> batch arrays -> driver -> named results.

This is the physics layer's bridge to the numerics: it checks that the time step divides the
output interval and the duration, takes one state row and one parameter row per body (packed
from `Scene`s, or as a sweep's batch takes them from its scene table's columns), and names the
slices of the sampled states. The run's steps and sample times are those of
`rbstudy.physics.time_grid`.
"""

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.numerics.driver import DRIFT_BOUND, BatchOutput, run_batch
from rbstudy.numerics.state import STATUS_NAMES
from rbstudy.physics.scenes import BatchRows, Scene, batch_rows
from rbstudy.physics.time_grid import output_count, output_times, step_count, steps_per
from rbstudy.schemes import get_scheme

__all__ = ["Simulation", "simulate"]


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

    def field(self, name: str) -> np.ndarray:
        """The samples of the state field ``name`` (`rbstudy.numerics.state.STATE_FIELDS`)."""
        return self.output.samples[:, :, S.STATE_FIELDS[name]]

    quaternion = property(lambda self: self.field("quaternion"))
    omega_body = property(lambda self: self.field("omega_body"))
    position = property(lambda self: self.field("position"))
    velocity = property(lambda self: self.field("velocity"))

    @property
    def results(self) -> dict[str, np.ndarray]:
        """Per-body results by name (`rbstudy.numerics.state.RESULT_FIELDS`), (B,) each."""
        return self.output.results

    @property
    def status_names(self) -> list[str]:
        """The name of each body's status (`rbstudy.numerics.state.STATUS_NAMES`)."""
        return [STATUS_NAMES[code] for code in self.results["status"]]


def simulate(
    scenes: Iterable[Scene] | BatchRows,
    scheme: str,
    dt: float,
    output_interval: float | None = None,
    options: Mapping | Sequence[Mapping] | np.ndarray | None = None,
    drift_bound: float = DRIFT_BOUND,
    threads: int | None = None,
) -> Simulation:
    """Integrate ``scenes`` (all of the same duration) with ``scheme`` at step ``dt``.

    Parameters
    ----------
    scenes : sequence of `rbstudy.physics.scenes.Scene`, one per body of the batch, or their
        rows as a sweep's batch takes them from its scene table
        (`rbstudy.physics.scenes.SceneTable.batch_rows`).
    scheme : registered scheme name.
    dt : time step (s); output_interval : sampling interval (s), default ``dt``.
    options : scheme options, one mapping for all scenes or a sequence of one per scene, or
        their rows (m, N_OPTION) as `rbstudy.schemes.Scheme.option_row` packs them.
    drift_bound : relative energy/|L| drift flagged as a blow-up.
    threads : threads to spread the bodies over (default: all cores).
    """
    batch = scenes if isinstance(scenes, BatchRows) else batch_rows(list(scenes))
    output_interval = dt if output_interval is None else output_interval
    n_steps = step_count(batch.duration, output_interval, dt)
    every = steps_per(output_interval, dt, "dt", "output interval")
    chosen = get_scheme(scheme)
    if isinstance(options, np.ndarray):
        rows = options
    elif options is None or isinstance(options, dict):
        rows = np.repeat(chosen.option_row(options)[None, :], len(batch.states), axis=0)
    else:
        rows = np.array([chosen.option_row(o) for o in options])
    output = run_batch(
        chosen, batch.states, batch.params, rows, dt, n_steps, every, drift_bound, threads=threads
    )
    return Simulation(
        scheme=scheme,
        dt=dt,
        time=output_times(output_count(batch.duration, output_interval), output_interval),
        output=output,
    )
