"""Loads that act in space on a turning body, read from a parameter row: constant space-fixed
forces at body-fixed points (the levers, `S.LEVER`), and the loads tabulated in time
(`S.KNOTS`), interpolated linearly between knots. `rbstudy.numerics.dynamics` sums them with
the other loads.
"""

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import add, axpy, cross, quat_rotate, quat_rotate_inverse, read3, sub

__all__ = [
    "lever_moment",
    "has_lever",
    "knot_segment",
    "tabulated3",
    "tabulated_moment",
    "tabulated_force",
]

# The rotation's columns, as `rbstudy.numerics.algebra` writes them for numpy code too.
rotation_columns = jit(algebra.rotation_columns)


@jit
def lever_moment(q, k1, k2, k3):
    """Space-frame moment of space-fixed forces at body-fixed points: ``sum_b c_b x k_b`` with
    ``c_b = R e_b`` the columns of the body's rotation.

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    k1, k2, k3 : tuple of 3 floats
        The rows ``k_b`` of `S.LEVER` (N m).

    Returns
    -------
    tuple of 3 floats
        N m, space axes.
    """
    c1, c2, c3 = rotation_columns(q)
    return add(add(cross(c1, k1), cross(c2, k2)), cross(c3, k3))


@jit
def has_lever(p):
    """Whether constant space-fixed forces act at points off the centre of mass.

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).

    Returns
    -------
    bool
    """
    for k in range(9):
        if p[S.LEVER + k] != 0.0:
            return True
    return False


@jit
def knot_segment(p, t):
    """Where a time falls among the knots of the tabulated loads of a row: ``t = (1 - s) t_k + s
    t_k+1``, ``0 <= s < 1``; ``s = 0`` at the first knot for earlier times and at the last knot
    for later ones (the loads are held there). Bisection: the knots are few, and a step may ask
    at any time.

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float
        Time (s).

    Returns
    -------
    k : int
        The knot at or before ``t``.
    s : float
        The fraction of the segment after it.
    """
    count = int(p[S.KNOTS])
    first = S.N_PARAM
    if t <= p[first]:
        return 0, 0.0
    if t >= p[first + count - 1]:
        return count - 1, 0.0
    low, high = 0, count - 1  # t_low < t < t_high
    while high - low > 1:
        middle = (low + high) // 2
        if p[first + middle] <= t:
            low = middle
        else:
            high = middle
    start = p[first + low]
    return low, (t - start) / (p[first + low + 1] - start)


@jit
def tabulated3(p, k, s, field):
    """A tabulated load at a place among the knots.

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    k, s : int, float
        The place (`knot_segment`).
    field : int
        The load's row index, FORCE_SPACE to LEVER + 6.

    Returns
    -------
    tuple of 3 floats
        The load there, interpolated linearly between knots.
    """
    at = S.N_PARAM + int(p[S.KNOTS]) + k * S.LOAD_RECORD + field - S.FORCE_SPACE
    value = read3(p, at)
    if s == 0.0:  # at or past a knot: the next record may not exist
        return value
    return axpy(s, sub(read3(p, at + S.LOAD_RECORD), value), value)


@jit
def tabulated_moment(q, p, t):
    """Body-frame moment of the loads tabulated in time (`S.KNOTS`).

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float
        Time (s).

    Returns
    -------
    tuple of 3 floats
        N m, body axes; zero for a row without tabulated loads.
    """
    if p[S.KNOTS] == 0.0:
        return (0.0, 0.0, 0.0)
    k, s = knot_segment(p, t)
    space = add(
        tabulated3(p, k, s, S.MOMENT_SPACE),
        lever_moment(
            q,
            tabulated3(p, k, s, S.LEVER),
            tabulated3(p, k, s, S.LEVER + 3),
            tabulated3(p, k, s, S.LEVER + 6),
        ),
    )
    return add(tabulated3(p, k, s, S.MOMENT_BODY), quat_rotate_inverse(q, space))


@jit
def tabulated_force(q, p, t):
    """Space force of the loads tabulated in time, weight included.

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float
        Time (s).

    Returns
    -------
    tuple of 3 floats
        N, space axes; zero for a row without tabulated loads.
    """
    if p[S.KNOTS] == 0.0:
        return (0.0, 0.0, 0.0)
    k, s = knot_segment(p, t)
    force = add(tabulated3(p, k, s, S.FORCE_SPACE), quat_rotate(q, tabulated3(p, k, s, S.FORCE_BODY)))
    return axpy(p[S.MASS], tabulated3(p, k, s, S.GRAVITY), force)
