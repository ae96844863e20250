"""Vectors between the body frame and the world for the engine adapters, by the formula of
the kernels and of the error measures (`rbstudy.numerics.algebra.rotation_columns`): an
engine that takes or gives the angular velocity in the world is converted here, once."""

import numpy as np

from rbstudy.numerics import algebra

__all__ = ["to_world", "to_body"]


def to_world(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R v`` (n, 3): the body-frame vectors ``v`` (n, 3) in the world, for the scalar-last
    unit quaternions ``q`` (n, 4) mapping body to world."""
    columns = algebra.rotation_columns(q.T)
    return sum(np.stack(column, axis=1) * v[:, k, None] for k, column in enumerate(columns))


def to_body(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R^T v`` (n, 3): the world vectors ``v`` (n, 3) in the body frame of ``q`` (n, 4)."""
    columns = algebra.rotation_columns(q.T)
    return np.stack(
        [sum(component * v[:, i] for i, component in enumerate(column)) for column in columns], axis=1
    )
