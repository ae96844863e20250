"""The compiled per-sample formulas of the output variables (`rbstudy.numerics.measures`):
against scipy's rotations (an independent oracle), and bit for bit against the numpy error
measures of `rbstudy.physics.metrics`, which the archives were written with before."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbstudy.numerics import measures
from rbstudy.physics import metrics
from rbstudy.physics.quaternions import quat_to_matrix

RNG = np.random.default_rng(33)
B, T, N = 40, 7, 3
# agreement with scipy's rotations: a few ulps of values of order one
RTOL = 1e-13
FAILS_AT = 4  # the sample at which every fifth case fails


def _samples():
    """(B, T, 13) samples laid out as the driver's (quaternion, omega, position, velocity),
    the last samples of a few cases failed (NaN), and one sample with a single infinite
    component."""
    samples = RNG.normal(size=(B, T, 13))
    samples[..., :4] = Rotation.random(B * T, random_state=RNG).as_quat().reshape(B, T, 4)
    samples[::5, FAILS_AT:] = np.nan
    samples[3, 2, 1] = np.inf
    return samples


SAMPLES = _samples()
QUATERNION, OMEGA = SAMPLES[..., 0:4], SAMPLES[..., 4:7]
POSITION, VELOCITY = SAMPLES[..., 7:10], SAMPLES[..., 10:13]
REFERENCE = Rotation.random(B * T, random_state=RNG).as_quat().reshape(B, T, 4)
REFERENCE_POSITION = RNG.normal(size=(B, T, 3))
OFFSETS = RNG.normal(size=(B, N, 3))
INERTIA = RNG.uniform(0.5, 2.0, size=(B, 3))
FAILED = ~np.all(np.isfinite(QUATERNION), axis=-1)  # (B, T)


def _rotations(quaternion):
    """scipy's rotations of (B, T, 4) quaternions, the identity at failed samples."""
    return Rotation.from_quat(np.where(FAILED[..., None], [0.0, 0.0, 0.0, 1.0], quaternion).reshape(-1, 4))


def _nodes(rotations, base, vectors):
    """``base + R v`` for (B, T, N, 3) vectors, NaN at failed samples."""
    turned = np.stack([rotations.apply(vectors[:, :, n].reshape(-1, 3)) for n in range(N)], axis=1)
    nodes = turned.reshape(B, T, N, 3) + base[:, :, None, :]
    nodes[FAILED] = np.nan
    return nodes


def test_a_failed_sample_is_nan_in_every_space_quantity():
    assert FAILED.sum() == B // 5 * (T - FAILS_AT) + 1  # and the infinite one
    for values in (
        measures.space_vectors(QUATERNION, OMEGA),
        measures.node_positions(QUATERNION, POSITION, OFFSETS),
        measures.node_velocities(QUATERNION, OMEGA, VELOCITY, OFFSETS),
    ):
        assert np.isnan(values[FAILED]).all()
        assert np.isfinite(values[~FAILED]).all()


def test_the_space_quantities_are_scipys_rotations():
    rotations = _rotations(QUATERNION)
    space = rotations.apply(OMEGA.reshape(-1, 3)).reshape(B, T, 3)
    space[FAILED] = np.nan
    np.testing.assert_allclose(measures.space_vectors(QUATERNION, OMEGA), space, rtol=RTOL, atol=RTOL)
    offsets = np.broadcast_to(OFFSETS[:, None], (B, T, N, 3))
    positions = _nodes(rotations, POSITION, offsets)
    np.testing.assert_allclose(
        measures.node_positions(QUATERNION, POSITION, OFFSETS), positions, rtol=RTOL, atol=RTOL
    )
    velocities = _nodes(rotations, VELOCITY, np.cross(OMEGA[:, :, None, :], offsets))
    np.testing.assert_allclose(
        measures.node_velocities(QUATERNION, OMEGA, VELOCITY, OFFSETS), velocities, rtol=RTOL, atol=RTOL
    )


def test_the_errors_are_scipys_rotations():
    rotations = _rotations(QUATERNION)
    reference = Rotation.from_quat(REFERENCE.reshape(-1, 4))
    vector, scalar = measures.orientation_parts(QUATERNION, REFERENCE)
    angle = (reference.inv() * rotations).magnitude().reshape(B, T)
    np.testing.assert_allclose(2.0 * np.arctan2(vector, scalar)[~FAILED], angle[~FAILED], atol=1e-12)

    momentum = rotations.apply((INERTIA[:, None, :] * OMEGA).reshape(-1, 3)).reshape(B, T, 3)
    expected = np.linalg.norm(momentum - momentum[:, :1], axis=-1) / np.linalg.norm(momentum[:, :1], axis=-1)
    got = measures.momentum_errors(QUATERNION, OMEGA, INERTIA)
    np.testing.assert_allclose(got[~FAILED], expected[~FAILED], atol=1e-12)

    nodes = measures.node_positions(QUATERNION, POSITION, OFFSETS)
    exact = _nodes(reference, REFERENCE_POSITION, np.broadcast_to(OFFSETS[:, None], (B, T, N, 3)))
    distances = measures.node_distances(nodes, REFERENCE, REFERENCE_POSITION, OFFSETS)
    np.testing.assert_allclose(distances, np.linalg.norm(nodes - exact, axis=-1), rtol=RTOL)


def _einsum_sums_as_turn():
    """Whether numpy's einsum sums a contraction of three contiguous terms as ``(j0 + j2) +
    j1`` on this machine, as on the AVX-512 machines the archives were written on (a tree
    sum of the vector's lanes; AVX2's sums them in order)."""
    a, b = RNG.normal(size=(2, 1000, 3))
    terms = a * b
    return np.array_equal(np.einsum("ij,ij->i", a, b), (terms[:, 0] + terms[:, 2]) + terms[:, 1])


@pytest.mark.skipif(not _einsum_sums_as_turn(), reason="numpy's einsum sums three terms in order here")
def test_bit_for_bit_the_numpy_measures():
    """The values the archives held before the measures were compiled: the numpy formulas of
    `rbstudy.physics.metrics` with the failed samples' orientations replaced by the identity
    and their space quantities by NaN, as `rbstudy.pipeline.outputs` did."""
    safe = np.where(FAILED[..., None], [0.0, 0.0, 0.0, 1.0], QUATERNION)
    positions = metrics.node_positions(safe, POSITION, OFFSETS)
    positions[FAILED] = np.nan
    assert np.array_equal(measures.node_positions(QUATERNION, POSITION, OFFSETS), positions, equal_nan=True)
    rotation = quat_to_matrix(safe)
    space = np.einsum("btij,btj->bti", rotation, OMEGA)
    space[FAILED] = np.nan
    assert np.array_equal(measures.space_vectors(QUATERNION, OMEGA), space, equal_nan=True)
    spin = np.cross(OMEGA[:, :, None, :], OFFSETS[:, None, :, :])
    velocities = np.einsum("btij,btnj->btni", rotation, spin) + VELOCITY[:, :, None, :]
    velocities[FAILED] = np.nan
    assert np.array_equal(
        measures.node_velocities(QUATERNION, OMEGA, VELOCITY, OFFSETS), velocities, equal_nan=True
    )
    assert np.array_equal(
        measures.momentum_errors(QUATERNION, OMEGA, INERTIA),
        metrics.momentum_error(QUATERNION, OMEGA, INERTIA[:, None, :]),
        equal_nan=True,
    )
    vector, scalar = measures.orientation_parts(QUATERNION, REFERENCE)
    assert np.array_equal(
        2.0 * np.arctan2(vector, scalar), metrics.orientation_error(QUATERNION, REFERENCE), equal_nan=True
    )
    exact = metrics.node_positions(REFERENCE, REFERENCE_POSITION, OFFSETS)
    assert np.array_equal(
        measures.node_distances(positions, REFERENCE, REFERENCE_POSITION, OFFSETS),
        metrics.node_error(positions, exact),
        equal_nan=True,
    )
    reference_omega = RNG.normal(size=(B, T, 3))
    assert np.array_equal(
        measures.relative_differences(OMEGA, reference_omega),
        metrics.omega_error(OMEGA, reference_omega),
        equal_nan=True,
    )
