"""The per-sample formulas of the archive's output variables, compiled: one pass over a
batch's B cases x T samples (x N nodes) each, where numpy took a few passes per formula
over (B, T, N, 3) arrays whose inner dimensions are 3 and 4 (docs/performance.md, "A
million cases").

`rbstudy.pipeline.outputs` calls them; `rbstudy.physics.metrics` keeps the same measures in
numpy for the readers, which load no numba. Every value is bit for bit what those numpy
formulas give (tests/test_measures.py): the same operations in the same order, with
`rbstudy.numerics.algebra`'s rotation matrix and Hamilton product, `rotation.cross` (numpy's
cross) and `rotation.norm` (numpy's norm of a 3-vector, the squares summed in order), and
no fused multiply-add (`fastmath` stays off). A product of a rotation matrix and a vector is
summed as numpy's einsum summed it where the archives were written: `turn`.

A sample "failed" where its quaternion has a non-finite component (the driver fills the
samples after a blow-up with NaN): the space quantities of a failed sample are NaN.
"""

import math

import numpy as np

from rbstudy.numerics import algebra
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import add, cross, norm, quat_mul, read3, read4, sub, write3

__all__ = [
    "turn",
    "space_vectors",
    "node_positions",
    "node_velocities",
    "node_distances",
    "momentum_errors",
    "orientation_parts",
    "relative_differences",
]

rotation_columns = jit(algebra.rotation_columns)


@jit
def _failed(q):
    return not (math.isfinite(q[0]) and math.isfinite(q[1]) and math.isfinite(q[2]) and math.isfinite(q[3]))


@jit
def turn(q, v):
    """``R(q) v``, each component's three products summed as ``(j = 0 + j = 2) + j = 1``.

    That is the order in which numpy's einsum summed a contraction of three contiguous terms
    on the AVX-512 machines the archives were written on (a tree sum of the vector's lanes);
    keeping it keeps them bit for bit.

    Parameters
    ----------
    q : tuple of 4 floats
        Quaternion, scalar last, body to space (its rotation matrix as
        `rbstudy.numerics.algebra.rotation_columns` forms it).
    v : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    c0, c1, c2 = rotation_columns(q)
    return (
        (c0[0] * v[0] + c2[0] * v[2]) + c1[0] * v[1],
        (c0[1] * v[0] + c2[1] * v[2]) + c1[1] * v[1],
        (c0[2] * v[0] + c2[2] * v[2]) + c1[2] * v[1],
    )


@jit
def space_vectors(quaternion, vectors):
    """Body vectors turned into space, ``R(q) v`` per sample.

    Parameters
    ----------
    quaternion : ndarray, shape (B, T, 4)
        Orientations, scalar last, body to space.
    vectors : ndarray, shape (B, T, 3)
        Vectors in body axes.

    Returns
    -------
    ndarray, shape (B, T, 3)
        In space axes; NaN where the sample failed.
    """
    n_cases, n_times = quaternion.shape[0], quaternion.shape[1]
    out = np.empty((n_cases, n_times, 3))
    for b in range(n_cases):
        for t in range(n_times):
            q = read4(quaternion[b, t], 0)
            write3(out[b, t], 0, (np.nan, np.nan, np.nan) if _failed(q) else turn(q, read3(vectors[b, t], 0)))
    return out


@jit
def _rigid_points(quaternion, base, offsets, omega):
    """``base + R(q) s`` per sample and node, or with ``omega`` not None ``base + R(q) (w x
    s)``: (B, T, N, 3), NaN where the sample failed."""
    n_cases, n_times, n_nodes = quaternion.shape[0], quaternion.shape[1], offsets.shape[1]
    out = np.full((n_cases, n_times, n_nodes, 3), np.nan)
    for b in range(n_cases):
        for t in range(n_times):
            q = read4(quaternion[b, t], 0)
            if _failed(q):
                continue
            for n in range(n_nodes):
                s = read3(offsets[b, n], 0)
                if omega is not None:
                    s = cross(read3(omega[b, t], 0), s)
                write3(out[b, t, n], 0, add(turn(q, s), read3(base[b, t], 0)))
    return out


@jit
def node_positions(quaternion, position, offsets):
    """Space positions of the nodes, ``R(q) s + x`` per sample and node.

    Parameters
    ----------
    quaternion : ndarray, shape (B, T, 4)
        Orientations, scalar last, body to space.
    position : ndarray, shape (B, T, 3)
        Centres of mass, m.
    offsets : ndarray, shape (B, N, 3)
        Node offsets from the centre of mass, principal axes, m.

    Returns
    -------
    ndarray, shape (B, T, N, 3)
        m; NaN where the sample failed.
    """
    return _rigid_points(quaternion, position, offsets, None)


@jit
def node_velocities(quaternion, omega, velocity, offsets):
    """Space velocities of the nodes, ``R(q) (w x s) + v`` per sample and node.

    Parameters
    ----------
    quaternion : ndarray, shape (B, T, 4)
        Orientations, scalar last, body to space.
    omega : ndarray, shape (B, T, 3)
        Body angular velocities, rad/s.
    velocity : ndarray, shape (B, T, 3)
        Centre-of-mass velocities, m/s.
    offsets : ndarray, shape (B, N, 3)
        Node offsets from the centre of mass, principal axes, m.

    Returns
    -------
    ndarray, shape (B, T, N, 3)
        m/s; NaN where the sample failed.
    """
    return _rigid_points(quaternion, velocity, offsets, omega)


@jit
def node_distances(nodes, quaternion, position, offsets):
    """Distances of nodes from their places in another motion, ``|x - (R(q) s + x_c)|``.

    Parameters
    ----------
    nodes : ndarray, shape (B, T, N, 3)
        Node positions, m.
    quaternion : ndarray, shape (B, T, 4)
        The other motion's orientations, scalar last, body to space (not checked: a NaN
        orientation gives NaN distances).
    position : ndarray, shape (B, T, 3)
        The other motion's centres of mass, m.
    offsets : ndarray, shape (B, N, 3)
        Node offsets from the centre of mass, principal axes, m.

    Returns
    -------
    ndarray, shape (B, T, N)
        m.
    """
    n_cases, n_times, n_nodes = nodes.shape[0], nodes.shape[1], nodes.shape[2]
    out = np.empty((n_cases, n_times, n_nodes))
    for b in range(n_cases):
        for t in range(n_times):
            q, x = read4(quaternion[b, t], 0), read3(position[b, t], 0)
            for n in range(n_nodes):
                place = add(turn(q, read3(offsets[b, n], 0)), x)
                out[b, t, n] = norm(sub(read3(nodes[b, t, n], 0), place))
    return out


@jit
def momentum_errors(quaternion, omega, inertia):
    """``|L(t) - L(0)| / |L(0)|`` of the space angular momentum ``L = R(q) (I w)``.

    Parameters
    ----------
    quaternion : ndarray, shape (B, T, 4)
        Orientations, scalar last, body to space (not checked: NaN gives NaN).
    omega : ndarray, shape (B, T, 3)
        Body angular velocities, rad/s.
    inertia : ndarray, shape (B, 3)
        Principal inertias, kg m^2.

    Returns
    -------
    ndarray, shape (B, T)
    """
    n_cases, n_times = quaternion.shape[0], quaternion.shape[1]
    out = np.empty((n_cases, n_times))
    for b in range(n_cases):
        i = read3(inertia[b], 0)
        start = (0.0, 0.0, 0.0)
        for t in range(n_times):
            w = read3(omega[b, t], 0)
            momentum = turn(read4(quaternion[b, t], 0), (i[0] * w[0], i[1] * w[1], i[2] * w[2]))
            if t == 0:
                start = momentum
            out[b, t] = norm(sub(momentum, start)) / norm(start)
    return out


@jit
def orientation_parts(quaternion, reference):
    """The vector part's length and the scalar part's magnitude of ``q_ref^-1 q``, whose
    angle ``2 atan2(|v|, |s|)`` is the orientation error (numpy takes the arctangent:
    its own differs from the C library's by an ulp here and there).

    Parameters
    ----------
    quaternion : ndarray, shape (B, T, 4)
        Orientations, scalar last.
    reference : ndarray, shape (B, T, 4)
        The reference's, unit quaternions.

    Returns
    -------
    vector : ndarray, shape (B, T)
        ``|v|``.
    scalar : ndarray, shape (B, T)
        ``|s|``.
    """
    n_cases, n_times = quaternion.shape[0], quaternion.shape[1]
    vector, scalar = np.empty((n_cases, n_times)), np.empty((n_cases, n_times))
    for b in range(n_cases):
        for t in range(n_times):
            r = read4(reference[b, t], 0)
            relative = quat_mul((-r[0], -r[1], -r[2], r[3]), read4(quaternion[b, t], 0))
            vector[b, t] = norm((relative[0], relative[1], relative[2]))
            scalar[b, t] = abs(relative[3])
    return vector, scalar


@jit
def relative_differences(values, reference):
    """``|a - a_ref| / |a_ref|`` of 3-vectors per sample.

    Parameters
    ----------
    values : ndarray, shape (B, T, 3)
    reference : ndarray, shape (B, T, 3)

    Returns
    -------
    ndarray, shape (B, T)
    """
    n_cases, n_times = values.shape[0], values.shape[1]
    out = np.empty((n_cases, n_times))
    for b in range(n_cases):
        for t in range(n_times):
            a_ref = read3(reference[b, t], 0)
            out[b, t] = norm(sub(read3(values[b, t], 0), a_ref)) / norm(a_ref)
    return out
