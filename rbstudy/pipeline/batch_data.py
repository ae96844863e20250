"""What the output variables of a batch are computed from: `BatchData`, the batch's columns.

A batch of B cases is held as columns (no object per case): its rows of the scene table,
its `Simulation` sampled at T times, its references on the same times, its kernel time. The
quantities several variables share (node positions, the orientation error, the measured and
exact precession and flip) are computed once per batch, on first use. Numba-free until a
quantity needs a compiled measure (`compiled_measures`): the archive readers import the
output functions' module, `rbstudy.pipeline.outputs`, which imports this one.
"""

from __future__ import annotations

from functools import cached_property
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from rbstudy.physics import analytic, metrics

if TYPE_CHECKING:  # the types alone: importing them loads numba
    from rbstudy.physics.reference_data import References
    from rbstudy.physics.scenes import SceneTable
    from rbstudy.physics.simulate import Simulation

__all__ = ["BatchData", "ACCURACY_BOUND", "compiled_measures"]

# The default accuracy bound (`output.accuracy_bound`): an orientation error of 0.01 rad
# or a 1% drift of energy or |L| is far outside any run worth reporting as accurate, yet well
# inside the blow-up bound (50%), so "finite but meaningless" gets its own verdict.
ACCURACY_BOUND = 1e-2

_UNCOSTED = (np.nan, np.nan)


def compiled_measures() -> ModuleType:
    """The compiled measures, imported at the first batch that needs them: the archive
    readers import this module, and must not load numba.

    Returns
    -------
    module
        `rbstudy.numerics.measures`.
    """
    from rbstudy.numerics import measures

    return measures


class BatchData:
    """What the variables of a batch of B cases are computed from, as columns (no object
    per case).

    table : the study's `rbstudy.physics.scenes.SceneTable`; rows : (B,) each case's row
    of it; run : their `Simulation` (T samples); references :
    `rbstudy.physics.references.References` (B cases on the same T times); run_time : (B,) s,
    kernel time per case; accuracy_bound : the study's bound on the orientation error (rad)
    and the relative energy and |L| drift of a case judged accurate; step_cost : the
    calibrated (s, relative uncertainty) of a body-step of the batch's run
    (`rbstudy.pipeline.calibration.StepCost`; NaN where not given).
    """

    def __init__(
        self,
        table: SceneTable,
        rows: np.ndarray,
        run: Simulation,
        references: References,
        run_time: float | np.ndarray,
        accuracy_bound: float = ACCURACY_BOUND,
        step_cost: tuple[float, float] = _UNCOSTED,
    ):
        self.table, self.rows, self.run, self.references = table, np.asarray(rows), run, references
        self.run_time = np.broadcast_to(np.asarray(run_time, dtype=float), self.rows.shape)
        self.accuracy_bound = accuracy_bound
        self.step_cost = step_cost

    @cached_property
    def principal_inertia(self) -> np.ndarray:
        """(B, 3) principal inertias, symmetrised as each `Body` does."""
        return analytic.symmetrised(self.table.inertia[self.rows])

    @cached_property
    def free(self) -> np.ndarray:
        """(B,) True where no moment acts."""
        return self.table.moment_free[self.rows]

    @cached_property
    def inertia(self) -> np.ndarray:
        """(B, 1, 3) principal inertias, broadcastable against (B, T, 3)."""
        return self.principal_inertia[:, None, :]

    @cached_property
    def node_offsets(self) -> np.ndarray:
        """(B, N, 3) node offsets from the centre of mass, principal axes."""
        return np.asarray(self.table.nodes[self.rows], dtype=float)

    @cached_property
    def node_positions(self) -> np.ndarray:
        """(B, T, N, 3) node positions in space, NaN after a failure."""
        return compiled_measures().node_positions(self.run.quaternion, self.run.position, self.node_offsets)

    def reference(self, name: str) -> np.ndarray:
        """One field of every case's reference.

        Parameters
        ----------
        name : str
            ``quaternion``, ``omega_body``, ``position`` or ``velocity``.

        Returns
        -------
        ndarray, shape (B, T, k)
            k = 4 for the quaternion, 3 for the others.
        """
        return getattr(self.references, name)

    @cached_property
    def orientation_error(self) -> np.ndarray:
        """(B, T) rad: `rbstudy.physics.metrics.orientation_error` of the samples."""
        vector, scalar = compiled_measures().orientation_parts(
            self.run.quaternion, self.reference("quaternion")
        )
        return 2.0 * np.arctan2(vector, scalar)

    @cached_property
    def measured_precession(self) -> np.ndarray:
        """(B,) rad/s: the phase rate of the transverse body rates of symmetric bodies."""
        axes = self.table.symmetry_axes[self.rows][:, None, None]
        omega = self.run.omega_body
        first = np.take_along_axis(omega, (axes + 1) % 3, axis=2)[..., 0]
        second = np.take_along_axis(omega, (axes + 2) % 3, axis=2)[..., 0]
        return metrics.phase_rate(first, second, self.run.time)

    @cached_property
    def exact_precession(self) -> np.ndarray:
        """(B,) rad/s: NaN where the body is not free and symmetric."""
        exact = analytic.precession_frequencies(self.principal_inertia, self.table.omega_body[self.rows])
        return np.where(self.free, exact, np.nan)

    @cached_property
    def middle_axes(self) -> np.ndarray:
        """(B,) each body's intermediate principal axis (0, 1 or 2)."""
        return np.argsort(self.principal_inertia, axis=1)[:, 1]

    @cached_property
    def middle_rates(self) -> np.ndarray:
        """(B, T) rad/s: each body's rate about its intermediate principal axis."""
        return np.take_along_axis(self.run.omega_body, self.middle_axes[:, None, None], axis=2)[..., 0]

    @cached_property
    def measured_flip(self) -> np.ndarray:
        """(B,) s: mean time between sign changes of each body's intermediate-axis rate."""
        time = self.run.time
        return np.array([metrics.sign_change_interval(rates, time) for rates in self.middle_rates])

    @cached_property
    def flip_counts(self) -> tuple[np.ndarray, np.ndarray]:
        """(B,) each, the sign changes of each body's intermediate-axis rate at the samples:
        the run's, and its exact solution's at the same samples (NaN where the body is not
        free and asymmetric, or its run failed)."""
        axes = self.middle_axes[:, None, None]
        exact = np.take_along_axis(self.reference("omega_body"), axes, axis=2)[..., 0]
        chosen = np.isfinite(self.exact_flip)
        run = np.where(chosen, metrics.sign_changes(self.middle_rates), np.nan)
        return run, np.where(chosen, metrics.sign_changes(exact), np.nan)

    @cached_property
    def separatrix(self) -> np.ndarray:
        """(B,) ``k'^2`` of each free asymmetric body (`analytic.separatrix_distance`), NaN
        for the others."""
        free = self.free & (self.table.symmetry_axes[self.rows] < 0)
        omega = self.table.omega_body[self.rows]
        return np.array(
            [
                analytic.separatrix_distance(inertia, spin) if chosen else np.nan
                for inertia, spin, chosen in zip(self.principal_inertia, omega, free, strict=True)
            ]
        )

    @cached_property
    def exact_flip(self) -> np.ndarray:
        """(B,) s: NaN where the body is not free and asymmetric (one case at a time: only
        studies of free asymmetric bodies store it)."""
        free = self.free & (self.table.symmetry_axes[self.rows] < 0)
        omega = self.table.omega_body[self.rows]
        return np.array(
            [
                analytic.flip_interval(inertia, spin) if chosen else np.nan
                for inertia, spin, chosen in zip(self.principal_inertia, omega, free, strict=True)
            ]
        )
