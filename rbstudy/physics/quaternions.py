"""Quaternion algebra on numpy arrays, vectorised over any leading axes (physics layer).

Scalar-last ``(x, y, z, w)`` like `scipy.spatial.transform.Rotation`. The numba kernels of
`rbstudy.numerics.rotation` work on one body's tuples; these work on whole trajectories and
batches. The Hamilton product is the kernels' own formula (`rbstudy.numerics.algebra`).
"""

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from rbstudy.numerics.algebra import hamilton_product, rotation_columns

__all__ = ["quat_mul", "quat_to_matrix", "rotvec_quaternion"]


def quat_mul(a: npt.ArrayLike, b: npt.ArrayLike) -> np.ndarray:
    """Hamilton products ``a * b`` of (..., 4) arrays (broadcast), by the kernels' formula."""
    return np.stack(
        hamilton_product(np.moveaxis(np.asarray(a), -1, 0), np.moveaxis(np.asarray(b), -1, 0)), axis=-1
    )


def quat_to_matrix(q: npt.ArrayLike) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    columns = rotation_columns(np.moveaxis(np.asarray(q), -1, 0))
    return np.stack([np.stack(column, axis=-1) for column in columns], axis=-1)


def rotvec_quaternion(v: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unit quaternions of rotation vectors: ``(sin(a/2) v/a, cos(a/2))``, component-first.

    ``v`` is a sequence of 3 arrays of one shape, the components (as the formulas of
    `rbstudy.numerics.algebra` take them: each component's array contiguous, where the
    rotation vectors of a batch of trajectories laid out (..., T, 3) were a few times
    slower); returns a tuple of 4 such arrays, scalar last. ``sin(a/2) / a`` is written as
    ``sinc`` so that a zero rotation needs no special case.
    """
    angle = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])  # np.linalg.norm's sum, in order
    scale = 0.5 * np.sinc(angle / (2.0 * np.pi))  # sin(a/2) / a
    return (v[0] * scale, v[1] * scale, v[2] * scale, np.cos(0.5 * angle))
