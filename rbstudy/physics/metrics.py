"""Error measures (docs/theory.md section 6), vectorised over any leading axes.

Array arguments carry the time axis ``T`` second to last for vectors: ``(..., T, 3)`` or
``(..., T, 4)``; scalars per time are ``(..., T)``.
"""

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from rbstudy.numerics.algebra import rotational_energy
from rbstudy.physics.quaternions import quat_mul, quat_to_matrix

__all__ = [
    "orientation_error",
    "omega_error",
    "node_positions",
    "node_error",
    "energy_error",
    "momentum_error",
    "phase_rate",
    "sign_change_interval",
    "sign_changes",
    "asymptotic_order",
    "OrderFit",
    "ORDER_SPREAD",
    "MAX_SLOPE_DRIFT",
    "MIN_ASYMPTOTIC_POINTS",
    "MIN_CONVERGENCE_ORDER",
    "ROUND_OFF_MARGIN",
    "UNCERTAIN_MEASURES",
]

# The error measures in which an integrated reference's uncertainty is given (its distance
# from its cross-check: `rbstudy.physics.references`), in the order of their columns; here,
# numba-free, for the archive's outputs to read.
UNCERTAIN_MEASURES = ("orientation", "omega", "nodes")

# Local slopes (between neighbouring dt) within this distance of the fitted order mark the
# asymptotic range, where the error behaves like C dt^p; half an order separates p = 1, 2, 4.
ORDER_SPREAD = 0.5
# Two points always agree with their own line: an asymptotic range needs three.
MIN_ASYMPTOTIC_POINTS = 3
# An error that shrinks more slowly than dt^0.5 is stalling or wandering, not converging.
MIN_CONVERGENCE_ORDER = 0.5
# Local slopes whose trend across a run falls (or rises) by more than this show an error not
# yet of the form C dt^p: with slopes 4.92 ... 4.09 towards small dt, a fit over all of them
# reports 4.5 for a fourth-order scheme.
MAX_SLOPE_DRIFT = 0.3
# A finer step whose error rises above the asymptotic run's finest error disproves the run,
# unless it is within this factor of the round-off floor (rounding may rise a little).
ROUND_OFF_MARGIN = 100.0


def orientation_error(q: npt.ArrayLike, q_ref: npt.ArrayLike) -> np.ndarray:
    """Geodesic angle (rad) between orientations: ``2 atan2(|v|, |s|)`` of ``q_ref^-1 q``.

    q, q_ref : (..., 4) scalar-last. Returns (...). Accurate at small angles (no acos).
    """
    conj = np.asarray(q_ref) * np.array([-1.0, -1.0, -1.0, 1.0])
    rel = quat_mul(conj, np.asarray(q))
    return 2.0 * np.arctan2(np.linalg.norm(rel[..., :3], axis=-1), np.abs(rel[..., 3]))


def omega_error(w: npt.ArrayLike, w_ref: np.ndarray) -> np.ndarray:
    """``|w - w_ref| / |w_ref|`` for (..., 3) angular velocities; returns (...)."""
    return np.linalg.norm(np.asarray(w) - w_ref, axis=-1) / np.linalg.norm(w_ref, axis=-1)


def node_positions(q: npt.ArrayLike, position: npt.ArrayLike, offsets: np.ndarray) -> np.ndarray:
    """Space positions (..., T, N, 3) of nodes with body offsets ``offsets``.

    q : (..., T, 4); position : (..., T, 3) centre of mass; offsets : (N, 3) or (..., N, 3),
    one set per leading index.
    """
    rotated = np.einsum("...tij,...nj->...tni", quat_to_matrix(q), offsets)
    return rotated + np.asarray(position)[..., None, :]


def node_error(x: npt.ArrayLike, x_ref: np.ndarray) -> np.ndarray:
    """``|x - x_ref|`` (m) for node positions (..., 3); returns (...)."""
    return np.linalg.norm(np.asarray(x) - x_ref, axis=-1)


def energy_error(w: npt.ArrayLike, inertia: npt.ArrayLike) -> np.ndarray:
    """Signed relative rotational energy error ``(T(t) - T(0)) / T(0)``.

    w (..., T, 3); inertia (3,) or broadcastable (..., 1, 3). Returns (..., T). The energy is
    the formula the driver checks every step with (`rbstudy.numerics.algebra`).
    """
    energy = rotational_energy(np.moveaxis(np.asarray(w), -1, 0), np.moveaxis(np.asarray(inertia), -1, 0))
    return energy / energy[..., :1] - 1.0


def momentum_error(q: npt.ArrayLike, w: np.ndarray, inertia: npt.ArrayLike) -> np.ndarray:
    """``|L(t) - L(0)| / |L(0)|`` of the space angular momentum ``L = R I w``.

    q (..., T, 4), w (..., T, 3), inertia (3,) or broadcastable (..., 1, 3); returns (..., T).
    """
    space = np.einsum("...ij,...j->...i", quat_to_matrix(q), np.asarray(inertia) * w)
    return np.linalg.norm(space - space[..., :1, :], axis=-1) / np.linalg.norm(space[..., :1, :], axis=-1)


def phase_rate(a: npt.ArrayLike, b: npt.ArrayLike, time: npt.ArrayLike) -> np.ndarray:
    """Least-squares slope (rad/s) of the unwrapped phase of ``a + i b`` against ``time``.

    a, b : (..., T); time : (T,). The precession frequency of a symmetric top is
    ``phase_rate(w1, w2, t)`` (body frame); its period seen in space is ``2 pi / rate`` of
    the space ``w_x, w_y``. NaN where any sample is non-finite.
    """
    phase = np.unwrap(np.arctan2(b, a), axis=-1)
    t = np.asarray(time, dtype=float)
    centred = t - t.mean()
    slope = np.sum((phase - phase.mean(axis=-1, keepdims=True)) * centred, axis=-1) / np.sum(centred**2)
    return np.where(np.all(np.isfinite(phase), axis=-1), slope, np.nan)


def sign_change_interval(values: npt.ArrayLike, time: npt.ArrayLike) -> float:
    """Mean time between sign changes of ``values`` (T,) sampled at ``time`` (T,), s.

    Each crossing is placed by linear interpolation between its two samples. NaN with fewer
    than two crossings or any non-finite sample (the flip interval of a free asymmetric body
    from its intermediate-axis rate).
    """
    values = np.asarray(values, dtype=float)
    time = np.asarray(time, dtype=float)
    if not np.all(np.isfinite(values)):
        return float("nan")
    k = np.flatnonzero(np.signbit(values[1:]) != np.signbit(values[:-1]))
    if k.size < 2:
        return float("nan")
    crossings = time[k] - values[k] * (time[k + 1] - time[k]) / (values[k + 1] - values[k])
    return float(np.diff(crossings).mean())


def sign_changes(values: npt.ArrayLike) -> np.ndarray:
    """How many times ``values`` (..., T) change sign between neighbouring samples, along the
    last axis (a free asymmetric body's flips, from its intermediate-axis rate): a float
    array of the leading shape, NaN where any sample is not finite."""
    values = np.asarray(values, dtype=float)
    counts = np.count_nonzero(np.signbit(values[..., 1:]) != np.signbit(values[..., :-1]), axis=-1)
    return np.where(np.all(np.isfinite(values), axis=-1), counts.astype(float), np.nan)


class OrderFit(NamedTuple):
    """An observed order: ``order`` fitted over the asymptotic range (NaN when there is none),
    ``used`` the mask of the points fitted, and ``finest_slope`` the local slope between the
    two finest of them (NaN when none), reported beside the fit."""

    order: float
    used: np.ndarray
    finest_slope: float


def asymptotic_order(
    dts: npt.ArrayLike,
    errors: npt.ArrayLike,
    floor: npt.ArrayLike = 1e-13,
    ceiling: float = 1e-1,
    spread: float = ORDER_SPREAD,
) -> OrderFit:
    """Observed convergence order: the least-squares slope of log(error) against log(dt) over
    the asymptotic range only, as an `OrderFit`.

    ``floor`` is one value or one per point (a point's error is not asymptotic below it: the
    round-off, or what the reference's own uncertainty lets the point show).

    The asymptotic range is the longest run of at least `MIN_ASYMPTOTIC_POINTS` neighbouring
    time steps whose errors lie between ``floor`` (round-off) and ``ceiling``, whose local
    slopes all lie within ``spread`` of their fitted order (itself at least
    `MIN_CONVERGENCE_ORDER`) and do not drift by more than `MAX_SLOPE_DRIFT` across the run
    (the least-squares trend of the local slopes, so that one noisy slope hides no drift: a
    pre-asymptotic range whose slopes still fall towards the order), and beyond whose finest
    step no finer step has a larger error (except within `ROUND_OFF_MARGIN` of the floor).
    Among runs of equal length the one at the finest steps wins: the finest steps above
    round-off are the most asymptotic. Unstable (NaN) points split runs.
    """
    dts = np.asarray(dts, dtype=float)
    errors = np.asarray(errors, dtype=float)
    floor = np.broadcast_to(np.asarray(floor, dtype=float), errors.shape)
    ascending = np.argsort(dts)
    usable = np.isfinite(errors) & (errors > floor) & (errors < ceiling)
    n = dts.size
    for length in range(n, MIN_ASYMPTOTIC_POINTS - 1, -1):
        for start in range(n - length + 1):
            run = ascending[start : start + length]
            if not usable[run].all():
                continue
            x, y = np.log(dts[run]), np.log(errors[run])
            order = float(np.polyfit(x, y, 1)[0])
            local = np.diff(y) / np.diff(x)  # finest pair first
            positions = np.arange(local.size)
            drift = abs(np.polyfit(positions, local, 1)[0]) * (local.size - 1)
            finer = ascending[:start]
            rises = np.any(errors[finer] > np.maximum(errors[run[0]], ROUND_OFF_MARGIN * floor[finer]))
            if (
                order >= MIN_CONVERGENCE_ORDER
                and not rises
                and drift <= MAX_SLOPE_DRIFT
                and np.all(np.abs(local - order) <= spread)
            ):
                used = np.zeros(n, dtype=bool)
                used[run] = True
                return OrderFit(order, used, float(local[0]))
    return OrderFit(float("nan"), np.zeros(n, dtype=bool), float("nan"))
