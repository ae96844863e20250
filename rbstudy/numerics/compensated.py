"""Compensated summation of a body's state updates (docs/theory.md s8).

A fixed-step scheme adds an increment to its state, ``y_n+1 = y_n + delta_n``. Rounded, each
sum loses up to half an ulp of ``y``, however small ``delta`` is: over n steps these errors
add up like a random walk of ``eps |y|`` per step, or linearly where the rounding is biased,
and a long run of a scheme whose truncation error is below it drowns in rounding. Carried
compensation keeps what each sum dropped and adds it back to the next increment, so that the
rounding left is that of the increments, ``eps |delta|``, dt times smaller (Kahan, Comm.
ACM 8 (1965) 40; Hairer, McLachlan & Razakarivony, BIT 48 (2008) 231, and Hairer's GNI
codes, which do this for every state update).

The carry of a body is a vector laid out like its state row (`rbstudy.numerics.state`),
``CARRY_WIDTH`` floats of the scheme's work array from an offset the scheme chooses; it
starts at zero (`rbstudy.numerics.driver` zeroes the work). The rounding error of each sum is
taken exactly (Knuth's two-sum, six additions), so the carry stays exact also where the
increment is larger than the value (a position that starts at zero). The kernels evaluate
their stages at the stored, rounded state: only the sums are compensated.

A rotation ``q <- q * r`` is written as the increment ``q * (r - 1)`` with ``r - 1`` computed
to its own relative accuracy (`rbstudy.numerics.rotation.quat_exp_minus_one` and its
siblings). A scheme that renormalises its quaternion does it as an increment too
(`normalize_inplace`): the correction is along ``q``, so its rounding moves the norm and not
the orientation, and the norm stays within a few ulps of 1 without drifting.

numba keeps the order of these operations (fastmath is off, `rbstudy.numerics.jit`): a
compiler allowed to reassociate would fold ``(a - s) + b`` to zero.
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import dot4, quat_mul, read4

__all__ = ["CARRY_WIDTH", "two_sum", "add3_inplace", "add4_inplace", "turn_inplace", "normalize_inplace"]

CARRY_WIDTH = S.N_STATE


@jit
def two_sum(a, b):
    """``(s, e)`` with ``s = fl(a + b)`` and ``a + b = s + e`` exactly (Knuth, TAOCP vol. 2,
    4.2.2), whatever the sizes of ``a`` and ``b``.

    Parameters
    ----------
    a, b : float

    Returns
    -------
    s : float
        The rounded sum.
    e : float
        Its rounding error.
    """
    s = a + b
    b_part = s - a
    a_part = s - b_part
    return s, (a - a_part) + (b - b_part)


@jit
def add3_inplace(y, k, delta, work, carry):
    """``y[k:k+3] += delta`` with compensation: the carry ``work[carry + k : carry + k + 3]``
    joins the increment, and keeps what the sum rounded off.

    Parameters
    ----------
    y : ndarray, shape (N_STATE,)
        The body's state row.
    k : int
        The first entry of the field (`rbstudy.numerics.state`).
    delta : tuple of 3 floats
        The increment.
    work : ndarray, shape (n_work,)
        The body's work, holding its carry.
    carry : int
        Where the carry starts in ``work`` (`CARRY_WIDTH` floats).
    """
    for i in range(3):
        y[k + i], work[carry + k + i] = two_sum(y[k + i], delta[i] + work[carry + k + i])


@jit
def add4_inplace(y, k, delta, work, carry):
    """`add3_inplace` for a field of 4 (the quaternion).

    Parameters
    ----------
    y : ndarray, shape (N_STATE,)
        The body's state row.
    k : int
        The first entry of the field.
    delta : tuple of 4 floats
        The increment.
    work : ndarray, shape (n_work,)
        The body's work, holding its carry.
    carry : int
        Where the carry starts in ``work``.
    """
    for i in range(4):
        y[k + i], work[carry + k + i] = two_sum(y[k + i], delta[i] + work[carry + k + i])


@jit
def normalize_inplace(y, work, carry):
    """Scale the compensated quaternion ``q + e`` of ``y`` to unit length, as the increment
    ``-r/2 q`` with ``r = |q + e|^2 - 1`` (``(1 + r)^(-1/2) = 1 - r/2`` to ``r^2``, below an
    ulp: ``r`` is a few ulps after a rotation, the truncation of rk4 per step otherwise).

    Parameters
    ----------
    y : ndarray, shape (N_STATE,)
        The body's state row.
    work : ndarray, shape (n_work,)
        The body's work, holding its carry.
    carry : int
        Where the carry starts in ``work``.
    """
    q = read4(y, S.QUATERNION)
    excess = (dot4(q, q) - 1.0) + 2.0 * dot4(q, read4(work, carry + S.QUATERNION))
    f = -0.5 * excess
    add4_inplace(y, S.QUATERNION, (f * q[0], f * q[1], f * q[2], f * q[3]), work, carry)


@jit
def turn_inplace(y, rotation_minus_one, work, carry):
    """``q <- q * r``, renormalised, with compensation, given ``r - 1`` (tuple of 4 floats,
    scalar last) to its own accuracy.

    Parameters
    ----------
    y : ndarray, shape (N_STATE,)
        The body's state row.
    rotation_minus_one : tuple of 4 floats
        ``r - 1`` for the unit quaternion ``r`` of the rotation.
    work : ndarray, shape (n_work,)
        The body's work, holding its carry.
    carry : int
        Where the carry starts in ``work``.
    """
    add4_inplace(y, S.QUATERNION, quat_mul(read4(y, S.QUATERNION), rotation_minus_one), work, carry)
    normalize_inplace(y, work, carry)
