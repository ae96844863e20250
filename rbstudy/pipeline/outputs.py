"""The functions that compute the output variables of a batch, one per variable.

`rbstudy.archive.variables` binds each to its name, units and needs. Every one takes
``batch : BatchData``, the B cases of a batch sampled at T times (N nodes), as columns
(`rbstudy.pipeline.batch_data`), and returns the variable's values with the case axis
first: (B, T, 3) for vectors over time, (B, T, N, 3) for nodes, (B,) per case; its
docstring's Returns gives the shape and units. Samples after a blow-up (a failure) are NaN;
every measure taken from them is NaN too.
"""

from collections.abc import Callable

import numpy as np

from rbstudy.archive.variables import ACCURATE, FAILED, INACCURATE, UNJUDGED
from rbstudy.numerics.state import OK, RESULT_FIELDS
from rbstudy.physics import analytic, metrics
from rbstudy.physics.scenes import triangle_ok
from rbstudy.pipeline.batch_data import BatchData, compiled_measures

__all__ = ["driver_result"]


def driver_result(name: str) -> Callable[[BatchData], np.ndarray]:
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

    def compute(batch: BatchData) -> np.ndarray:
        return batch.run.results[name]

    compute.__name__ = name
    return compute


def omega_body(batch: BatchData) -> np.ndarray:
    """Angular velocity in the body's principal axes.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T, 3)
        rad/s; NaN after a failure.
    """
    return batch.run.omega_body


def omega_space(batch: BatchData) -> np.ndarray:
    """Angular velocity in space.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T, 3)
        rad/s; NaN after a failure.
    """
    return compiled_measures().space_vectors(batch.run.quaternion, batch.run.omega_body)


def quaternion(batch: BatchData) -> np.ndarray:
    """Orientation, scalar last, body to space.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T, 4)
        NaN after a failure.
    """
    return batch.run.quaternion


def position(batch: BatchData) -> np.ndarray:
    """Centre-of-mass position in space.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T, 3)
        m; NaN after a failure.
    """
    return batch.run.position


def node_displacement(batch: BatchData) -> np.ndarray:
    """Displacement of every node from its place at t = 0.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T, N, 3)
        m, space axes; NaN after a failure.
    """
    return batch.node_positions - batch.node_positions[:, :1]


def node_velocity(batch: BatchData) -> np.ndarray:
    """Space velocity of every node, ``v_i = v + R (w x s_i)`` (s_i its body offset).

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T, N, 3)
        m/s; NaN after a failure.
    """
    run = batch.run
    return compiled_measures().node_velocities(
        run.quaternion, run.omega_body, run.velocity, batch.node_offsets
    )


def energy_error(batch: BatchData) -> np.ndarray:
    """Relative rotational energy error ``(T - T0) / T0``, signed.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T)
        NaN after a failure.
    """
    return metrics.energy_error(batch.run.omega_body, batch.inertia)


def momentum_error(batch: BatchData) -> np.ndarray:
    """Relative angular momentum error ``|L - L0| / |L0|`` of L in space.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T)
        NaN after a failure.
    """
    return compiled_measures().momentum_errors(
        batch.run.quaternion, batch.run.omega_body, batch.principal_inertia
    )


def orientation_error(batch: BatchData) -> np.ndarray:
    """Angle of the rotation between the orientation and the reference's.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T)
        rad; NaN after a failure.
    """
    return batch.orientation_error


def omega_error(batch: BatchData) -> np.ndarray:
    """Relative angular velocity error ``|w - w_ref| / |w_ref|`` in body axes.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T)
        NaN after a failure.
    """
    return compiled_measures().relative_differences(batch.run.omega_body, batch.reference("omega_body"))


def node_error(batch: BatchData) -> np.ndarray:
    """Distance of every node from its place in the reference motion.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, T, N)
        m; NaN after a failure.
    """
    return compiled_measures().node_distances(
        batch.node_positions, batch.reference("quaternion"), batch.reference("position"), batch.node_offsets
    )


def precession_frequency(batch: BatchData) -> np.ndarray:
    """Measured precession rate of a symmetric body (the phase rate of its transverse body
    rates).

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        rad/s
    """
    return batch.measured_precession


def precession_frequency_exact(batch: BatchData) -> np.ndarray:
    """Exact precession rate of a free symmetric body.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        rad/s (a free symmetric body).
    """
    return batch.exact_precession


def precession_frequency_error(batch: BatchData) -> np.ndarray:
    """Measured minus exact precession rate.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        rad/s
    """
    return batch.measured_precession - batch.exact_precession


def flip_interval(batch: BatchData) -> np.ndarray:
    """Measured mean time between sign changes of the intermediate-axis rate.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return batch.measured_flip


def flip_interval_exact(batch: BatchData) -> np.ndarray:
    """Exact time between sign changes of the intermediate-axis rate.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        s (a free asymmetric body).
    """
    return batch.exact_flip


def flip_interval_error(batch: BatchData) -> np.ndarray:
    """Measured minus exact flip interval.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return batch.measured_flip - batch.exact_flip


def flip_count(batch: BatchData) -> np.ndarray:
    """Sign changes of the intermediate-axis rate at the samples: the run's flips.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        1 (a count; NaN where the run failed)
    """
    return batch.flip_counts[0]


def separatrix_distance(batch: BatchData) -> np.ndarray:
    """``k'^2``: how far a free asymmetric body's motion lies from the separatrix.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        1 (0 on the separatrix)
    """
    return batch.separatrix


def flip_count_exact(batch: BatchData) -> np.ndarray:
    """Sign changes of the exact solution's intermediate-axis rate at the same samples.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        1 (a count)
    """
    return batch.flip_counts[1]


def run_time(batch: BatchData) -> np.ndarray:
    """Kernel time of each case.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return batch.run_time


def step_seconds(batch: BatchData) -> np.ndarray:
    """Calibrated kernel time of a body-step of each case's run.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        s
    """
    return np.full(batch.rows.shape, float(batch.step_cost[0]))


def step_seconds_uncertainty(batch: BatchData) -> np.ndarray:
    """Relative uncertainty of `step_seconds`.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        1
    """
    return np.full(batch.rows.shape, float(batch.step_cost[1]))


def final_orientation_error(batch: BatchData) -> np.ndarray:
    """Orientation error at the last output time.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        rad; NaN after a failure.
    """
    return batch.orientation_error[:, -1]


def accuracy(batch: BatchData) -> np.ndarray:
    """The accuracy verdict of each case (`VERDICTS`).

    A finished case is inaccurate when its orientation error at any sample (rad), or its
    relative energy or |L| drift over the steps (moment-free bodies), passes the
    accuracy bound. The largest error, not the final one: an error that wrapped round
    by the end of the run still was one. A finished case with no reference and no
    drift past the bound is unjudged, not accurate.

    Parameters
    ----------
    batch : BatchData

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


def inertia(batch: BatchData) -> np.ndarray:
    """Principal inertias.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, 3)
        kg m^2
    """
    return batch.inertia[:, 0, :]


def initial_spin(batch: BatchData) -> np.ndarray:
    """``|w|`` at t = 0.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        rad/s
    """
    return np.linalg.norm(batch.run.omega_body[:, 0], axis=-1)


def node_offset(batch: BatchData) -> np.ndarray:
    """Node offsets from the centre of mass, principal axes.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B, N, 3)
        m
    """
    return batch.node_offsets


def regularised_inertia(batch: BatchData) -> np.ndarray:
    """Whether a principal inertia was raised (an assembled body).

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        int8: 0 as assembled, 1 regularised.
    """
    regularised = batch.table.regularised
    if regularised is None:
        return np.zeros(len(batch.rows), dtype=np.int8)
    return np.asarray(regularised[batch.rows], dtype=np.int8)


def physical_body(batch: BatchData) -> np.ndarray:
    """Whether the body is physical (0: an ``allow_unphysical`` stress body).

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        int8
    """
    return np.asarray(triangle_ok(batch.principal_inertia), dtype=np.int8)
