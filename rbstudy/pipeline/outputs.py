"""The functions that compute the output variables of a batch, one per variable.

Each takes a `BatchData` (the batch's rows of the scene table, its `Simulation`, its
references as columns and run time)
and returns the variable's values with the case axis first: (B, T, 3) for vectors over time,
(B, T, N, 3) for nodes, (B,) per case. `rbstudy.archive.variables` binds each to its name,
units and needs. Quantities several variables share (node positions, the
orientation error) are computed once per batch, on first use. Samples after a blow-up are NaN;
every measure taken from them is NaN too.
"""

from functools import cached_property

import numpy as np

from rbstudy.archive.variables import ACCURATE, FAILED, INACCURATE, UNJUDGED
from rbstudy.numerics.state import OK, RESULT_FIELDS
from rbstudy.physics import analytic, metrics
from rbstudy.physics.scenes import triangle_ok

__all__ = [
    "BatchData",
    "driver_result",
    "ACCURACY_BOUND",
]

# The default accuracy bound (`output.accuracy_bound`): an orientation error of 0.01 rad
# or a 1% drift of energy or |L| is far outside any run worth reporting as accurate, yet well
# inside the blow-up bound (50%), so "finite but meaningless" gets its own verdict.
ACCURACY_BOUND = 1e-2


def _compiled():
    """`rbstudy.numerics.measures`, imported at the first batch: the archive readers import
    this module, and must not load numba."""
    from rbstudy.numerics import measures

    return measures


_UNCOSTED = (np.nan, np.nan)


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
        self, table, rows, run, references, run_time, accuracy_bound=ACCURACY_BOUND, step_cost=_UNCOSTED
    ):
        self.table, self.rows, self.run, self.references = table, np.asarray(rows), run, references
        self.run_time = np.broadcast_to(np.asarray(run_time, dtype=float), self.rows.shape)
        self.accuracy_bound = accuracy_bound
        self.step_cost = step_cost

    @cached_property
    def principal_inertia(self):
        """(B, 3) principal inertias, symmetrised as each `Body` does."""
        return analytic.symmetrised(self.table.inertia[self.rows])

    @cached_property
    def free(self):
        """(B,) True where no moment acts."""
        return self.table.moment_free[self.rows]

    @cached_property
    def inertia(self):
        """(B, 1, 3) principal inertias, broadcastable against (B, T, 3)."""
        return self.principal_inertia[:, None, :]

    @cached_property
    def node_offsets(self):
        """(B, N, 3) node offsets from the centre of mass, principal axes."""
        return np.asarray(self.table.nodes[self.rows], dtype=float)

    @cached_property
    def node_positions(self):
        """(B, T, N, 3) node positions in space, NaN after a failure."""
        return _compiled().node_positions(self.run.quaternion, self.run.position, self.node_offsets)

    def reference(self, name):
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
    def orientation_error(self):
        """(B, T) rad: `rbstudy.physics.metrics.orientation_error` of the samples."""
        vector, scalar = _compiled().orientation_parts(self.run.quaternion, self.reference("quaternion"))
        return 2.0 * np.arctan2(vector, scalar)

    @cached_property
    def measured_precession(self):
        """(B,) rad/s: the phase rate of the transverse body rates of symmetric bodies."""
        axes = self.table.symmetry_axes[self.rows][:, None, None]
        omega = self.run.omega_body
        first = np.take_along_axis(omega, (axes + 1) % 3, axis=2)[..., 0]
        second = np.take_along_axis(omega, (axes + 2) % 3, axis=2)[..., 0]
        return metrics.phase_rate(first, second, self.run.time)

    @cached_property
    def exact_precession(self):
        """(B,) rad/s: NaN where the body is not free and symmetric."""
        exact = analytic.precession_frequencies(self.principal_inertia, self.table.omega_body[self.rows])
        return np.where(self.free, exact, np.nan)

    @cached_property
    def measured_flip(self):
        """(B,) s: mean time between sign changes of each body's intermediate-axis rate."""
        middle = np.argsort(self.principal_inertia, axis=1)[:, 1]
        omega, time = self.run.omega_body, self.run.time
        return np.array(
            [metrics.sign_change_interval(omega[b, :, axis], time) for b, axis in enumerate(middle)]
        )

    @cached_property
    def exact_flip(self):
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


def driver_result(name):
    """The compute function of one of the driver's per-body results.

    Parameters
    ----------
    name : str
        A name of `rbstudy.numerics.state.RESULT_FIELDS`.

    Returns
    -------
    callable ``(batch) -> ndarray, shape (B,)``
        Named ``name``.

    Raises
    ------
    ValueError
        Where the driver reports no ``name``.
    """
    if name not in dict(RESULT_FIELDS):
        raise ValueError(f"the driver reports no {name!r}")

    def compute(batch):
        return batch.run.results[name]

    compute.__name__ = name
    return compute


def omega_body(batch):
    """Angular velocity in the body's principal axes.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T, 3)
        rad/s; NaN after a failure.
    """
    return batch.run.omega_body


def omega_space(batch):
    """Angular velocity in space.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T, 3)
        rad/s; NaN after a failure.
    """
    return _compiled().space_vectors(batch.run.quaternion, batch.run.omega_body)


def quaternion(batch):
    """Orientation, scalar last, body to space.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T, 4)
        NaN after a failure.
    """
    return batch.run.quaternion


def position(batch):
    """Centre-of-mass position in space.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T, 3)
        m; NaN after a failure.
    """
    return batch.run.position


def node_displacement(batch):
    """Displacement of every node from its place at t = 0.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T, N, 3)
        m, space axes; NaN after a failure.
    """
    return batch.node_positions - batch.node_positions[:, :1]


def node_velocity(batch):
    """Space velocity of every node, ``v_i = v + R (w x s_i)`` (s_i its body offset).

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T, N, 3)
        m/s; NaN after a failure.
    """
    run = batch.run
    return _compiled().node_velocities(run.quaternion, run.omega_body, run.velocity, batch.node_offsets)


def energy_error(batch):
    """Relative rotational energy error ``(T - T0) / T0``, signed.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T)
        NaN after a failure.
    """
    return metrics.energy_error(batch.run.omega_body, batch.inertia)


def momentum_error(batch):
    """Relative angular momentum error ``|L - L0| / |L0|`` of L in space.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T)
        NaN after a failure.
    """
    return _compiled().momentum_errors(batch.run.quaternion, batch.run.omega_body, batch.principal_inertia)


def orientation_error(batch):
    """Angle of the rotation between the orientation and the reference's.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T)
        rad; NaN after a failure.
    """
    return batch.orientation_error


def omega_error(batch):
    """Relative angular velocity error ``|w - w_ref| / |w_ref|`` in body axes.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T)
        NaN after a failure.
    """
    return _compiled().relative_differences(batch.run.omega_body, batch.reference("omega_body"))


def node_error(batch):
    """Distance of every node from its place in the reference motion.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, T, N)
        m; NaN after a failure.
    """
    return _compiled().node_distances(
        batch.node_positions, batch.reference("quaternion"), batch.reference("position"), batch.node_offsets
    )


def precession_frequency(batch):
    """Measured precession rate of a symmetric body (the phase rate of its transverse body
    rates).

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        rad/s
    """
    return batch.measured_precession


def precession_frequency_exact(batch):
    """Exact precession rate of a free symmetric body.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        rad/s (a free symmetric body).
    """
    return batch.exact_precession


def precession_frequency_error(batch):
    """Measured minus exact precession rate.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        rad/s
    """
    return batch.measured_precession - batch.exact_precession


def flip_interval(batch):
    """Measured mean time between sign changes of the intermediate-axis rate.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return batch.measured_flip


def flip_interval_exact(batch):
    """Exact time between sign changes of the intermediate-axis rate.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        s (a free asymmetric body).
    """
    return batch.exact_flip


def flip_interval_error(batch):
    """Measured minus exact flip interval.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return batch.measured_flip - batch.exact_flip


def run_time(batch):
    """Kernel time of each case.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return batch.run_time


def step_seconds(batch):
    """Calibrated kernel time of a body-step of each case's run.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return np.full(batch.rows.shape, float(batch.step_cost[0]))


def step_seconds_uncertainty(batch):
    """Relative uncertainty of `step_seconds`.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        1
    """
    return np.full(batch.rows.shape, float(batch.step_cost[1]))


def final_orientation_error(batch):
    """Orientation error at the last output time.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        rad; NaN after a failure.
    """
    return batch.orientation_error[:, -1]


def accuracy(batch):
    """The accuracy verdict of each case (`VERDICTS`).

    A finished case is inaccurate when its orientation error at any sample (rad), or its
    relative energy or |L| drift over the steps (moment-free bodies), passes the
    accuracy bound. The largest error, not the final one: an error that wrapped round
    by the end of the run still was one. A finished case with no reference and no
    drift past the bound is unjudged, not accurate.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        int8: 0 accurate, 1 inaccurate, 2 failed, 3 unjudged.
    """
    results, bound = batch.run.results, batch.accuracy_bound
    # NaN drifts (under moments: no conserved quantity) compare False: no drift past the bound
    drifted = (results["max_energy_error"] > bound) | (results["max_momentum_magnitude_error"] > bound)
    with np.errstate(invalid="ignore"):
        accurate = (np.max(batch.orientation_error, axis=1) <= bound) & ~drifted
    unreferenced = batch.references.code == analytic.REFERENCE_KINDS.index("none")
    verdict = np.where(accurate, ACCURATE, np.where(unreferenced & ~drifted, UNJUDGED, INACCURATE))
    return np.where(results["status"] == OK, verdict, FAILED).astype(np.int8)


def reference(batch):
    """The code of each case's reference in `rbstudy.physics.analytic.REFERENCE_KINDS`.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        int8
    """
    return batch.references.code.astype(np.int8)


def _uncertainty(batch, measure):
    """(B,) the reference's uncertainty in ``measure``: NaN where nothing checked it."""
    return batch.references.uncertainty[:, metrics.UNCERTAIN_MEASURES.index(measure)]


def reference_uncertainty(batch):
    """The reference's uncertainty in orientation.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        rad; NaN where nothing checked it.
    """
    return _uncertainty(batch, "orientation")


def reference_omega_uncertainty(batch):
    """The reference's relative uncertainty in body angular velocity.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        NaN where nothing checked it.
    """
    return _uncertainty(batch, "omega")


def reference_node_uncertainty(batch):
    """The reference's uncertainty in node positions.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        m; NaN where nothing checked it.
    """
    return _uncertainty(batch, "nodes")


def inertia(batch):
    """Principal inertias.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, 3)
        kg m^2
    """
    return batch.inertia[:, 0, :]


def initial_spin(batch):
    """``|w|`` at t = 0.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        rad/s
    """
    return np.linalg.norm(batch.run.omega_body[:, 0], axis=-1)


def node_offset(batch):
    """Node offsets from the centre of mass, principal axes.

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B, N, 3)
        m
    """
    return batch.node_offsets


def regularised_inertia(batch):
    """Whether a principal inertia was raised (an assembled body).

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        int8: 0 as assembled, 1 regularised.
    """
    regularised = batch.table.regularised
    if regularised is None:
        return np.zeros(len(batch.rows), dtype=np.int8)
    return np.asarray(regularised[batch.rows], dtype=np.int8)


def physical_body(batch):
    """Whether the body is physical (0: an ``allow_unphysical`` stress body).

    Parameters
    ----------
    batch : BatchData
        B cases sampled at T times (N nodes).

    Returns
    -------
    ndarray, shape (B,)
        int8
    """
    return triangle_ok(batch.principal_inertia).astype(np.int8)
