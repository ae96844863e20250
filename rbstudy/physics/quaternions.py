"""Quaternion algebra on numpy arrays, vectorised over any leading axes (physics layer).

Scalar-last ``(x, y, z, w)`` like `scipy.spatial.transform.Rotation`. The numba kernels of
`rbstudy.numerics.rotation` work on one body's tuples; these work on whole trajectories and
batches. The Hamilton product is the kernels' own formula (`rbstudy.numerics.algebra`).
"""

import numpy as np

from rbstudy.numerics.algebra import hamilton_product, rotation_columns

__all__ = ["quat_mul", "quat_to_matrix", "quat_from_rotvec"]


def quat_mul(a, b):
    """Hamilton products ``a * b`` of (..., 4) arrays (broadcast), by the kernels' formula."""
    return np.stack(
        hamilton_product(np.moveaxis(np.asarray(a), -1, 0), np.moveaxis(np.asarray(b), -1, 0)), axis=-1
    )


def quat_to_matrix(q):
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    columns = rotation_columns(np.moveaxis(np.asarray(q), -1, 0))
    return np.stack([np.stack(column, axis=-1) for column in columns], axis=-1)


def quat_from_rotvec(v):
    """Unit quaternions (..., 4) of rotation vectors (..., 3): ``(sin(a/2) v/a, cos(a/2))``.

    ``sin(a/2) / a`` is written as ``sinc`` so that a zero rotation needs no special case.
    """
    v = np.asarray(v, dtype=float)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    scale = 0.5 * np.sinc(angle / (2.0 * np.pi))  # sin(a/2) / a
    return np.concatenate([v * scale, np.cos(0.5 * angle)], axis=-1)
