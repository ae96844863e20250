"""The exact flow of the free rigid body, any principal inertias: a scalar kernel, and a
batch of bodies at many times.

For a body with principal inertias ``I``, orientation ``q`` (body to space) and body angular
velocity ``w``, `free_flow` returns the state after a time ``t`` of force-free motion
(docs/theory.md, section 3; Landau and Lifshitz, Mechanics, section 37; E. Celledoni,
F. Fasso, N. Safstrom, A. Zanna, "The exact computation of the free rigid body motion and
its use in splitting methods", SIAM J. Sci. Comput. 30 (2008) 2084-2112):

1. With ``m = I w``, ``G = |m|`` and ``d_j = G^2 - 2 E I_j`` (summed term by term,
   ``sum_{n != j} m_n^2 (I_n - I_j) / I_n``, free of cancellation), the body circulates about
   its largest axis when ``d`` of the intermediate one is positive, else about its smallest.
   A right-handed relabelling of the axes (a permutation, one axis negated if it is odd)
   makes the circulation axis the third and the intermediate one the second.
2. ``w1 = a1 cn u``, ``w2 = a2 sn u``, ``w3 = a3 dn u``, ``u = lambda t + u0``, with
   ``a1^2 = -d3 / (I1 (I3 - I1))``, ``a2^2 = -d3 / (I2 (I3 - I2))``,
   ``a3^2 = d1 / (I3 (I3 - I1))``, ``lambda^2 = (I3 - I2) d1 / (I1 I2 I3)``,
   ``k^2 = (I2 - I1)(-d3) / ((I3 - I2) d1)`` and ``k'^2 = (I3 - I1) d2 / ((I3 - I2) d1)``.
   ``a2 > 0``; ``a1`` and ``a3`` take the signs of ``w1(0)`` and ``w3(0)`` (``dn`` never
   changes sign, and on the separatrix neither does ``cn``), and Euler's first equation
   gives ``lambda = (I3 - I2) a2 a3 / (I1 a1)`` its sign. ``u0 = F(phi0 | k^2)`` with
   ``(sin, cos) phi0 = (w2 / a2, w1 / a1)`` and ``dn u0 = w3 / a3``.
3. With ``L = R m`` fixed in space, the z-x-z angles of the body from a frame whose third
   axis is ``L`` are ``cos theta = m3 / G``, ``psi = atan2(m1, m2)`` and
   ``phi(t) - phi(0) = G t / I3 + G (I3 - I1) / (I1 I3 lambda)
   [Pi(n; am u | k^2) - Pi(n; am u0 | k^2)]``, ``n = -I3 (I2 - I1) / (I1 (I3 - I2))``.
   So ``R(t) = R(0) P^T B(0)^T Rot(e3, phi(t) - phi(0)) B(t) P``, ``B = Rot(e1, theta)
   Rot(e3, psi)`` and ``P`` the relabelling: no fixed frame of ``L`` is ever built.
   ``psi`` is taken from ``(sn, cn)`` rather than from ``m`` so that it stays defined as the
   amplitudes vanish (a rotation close to a permanent one).

Long runs: ``w`` has the period ``4K / |lambda|``, and over each period the precession angle
advances by the same amount. The time is reduced modulo the period and the whole periods
are added as a multiple of that advance, computed once: nothing is integrated, and the
error grows no faster than linearly with ``t`` (the rounding of ``t`` and of the period).

`free_body` computes a body's constants once (the relabelling, amplitudes, rate, the complete
integrals, ``u0``, the period and its advance); `free_motion` evaluates them at a time. The
batch of the references takes the constants once per body; a step of a splitting scheme once
per step.

Permanent rotations (``m x w = 0``: about a principal axis, any axis of a spherical body, an
axis in the plane of equal moments of a symmetric one) turn at constant ``w``. The
separatrix (``k' = 0``) takes ``sn = tanh``, ``cn = dn = sech`` and the closed form
``Pi(n; am u | 1) = (u + sqrt(a) atan(sqrt(a) tanh u)) / (1 + a)``, ``a = -n``.
"""

import math
from collections import namedtuple

from rbstudy.numerics import algebra
from rbstudy.numerics.elliptic import (
    complete_first,
    complete_third,
    first_kind,
    jacobi,
    third_kind,
)
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import (
    cross,
    quat_conj,
    quat_mul,
    quat_mul_axis_rotation,
    read3,
    read4,
    spun_steadily,
    write3,
    write4,
)

__all__ = ["FreeBody", "free_body", "free_motion", "free_flow", "free_flow_batch"]

momentum_excess = jit(algebra.momentum_excess)
circulation_axes = jit(algebra.circulation_axes)

# The constants of one body's free motion, in the relabelled frame (module docstring).
# ``steady``: a permanent rotation at ``omega0``, the other fields unused. ``first, mid,
# third, sign``: the relabelling. ``quarter``, ``whole``: K and Pi(n), inf on the separatrix
# (``k2c = 0``), where ``period`` and ``advance`` are unused. ``tilt0``: B(0) as a quaternion.
FreeBody = namedtuple(
    "FreeBody",
    [
        "steady",
        "omega0",
        "first",
        "mid",
        "third",
        "sign",
        "i1",
        "i2",
        "i3",
        "a1",
        "a2",
        "a3",
        "rate",
        "k2",
        "k2c",
        "n",
        "g",
        "coefficient",
        "u0",
        "third_start",
        "quarter",
        "whole",
        "period",
        "advance",
        "tilt0",
    ],
)


@jit
def _tilt(i1, i2, i3, a1, a2, a3, sn, cn, dn):
    """The quaternion of ``B = Rot(e1, theta) Rot(e3, psi)``, which takes ``m`` to ``G e3``,
    in the relabelled frame."""
    theta = math.atan2(math.hypot(i1 * a1 * cn, i2 * a2 * sn), i3 * a3 * dn)
    psi = math.atan2(math.copysign(math.sqrt(i1 * abs(i3 - i2)), a1) * cn, math.sqrt(i2 * abs(i3 - i1)) * sn)
    tilt = (math.sin(0.5 * theta), 0.0, 0.0, math.cos(0.5 * theta))
    return quat_mul_axis_rotation(tilt, 2, math.sin(0.5 * psi), math.cos(0.5 * psi))


@jit
def _separatrix_third(n, u):
    """``Pi(n; am u | 1) = (u + sqrt(a) atan(sqrt(a) tanh u)) / (1 + a)``, ``a = -n``."""
    root = math.sqrt(-n)
    return (u + root * math.atan(root * math.tanh(u))) / (1.0 - n)


@jit
def _steady(omega):
    return FreeBody(
        True,
        omega,
        0,
        1,
        2,
        1.0,
        1.0,
        1.0,
        1.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        (0.0, 0.0, 0.0, 1.0),
    )


@jit
def free_body(inertia, omega):
    """The constants of the free motion of a body.

    Parameters
    ----------
    inertia : tuple of 3 floats
        Principal inertias (kg m^2), any order, positive.
    omega : tuple of 3 floats
        Body angular velocity (rad/s).

    Returns
    -------
    FreeBody
    """
    m = (inertia[0] * omega[0], inertia[1] * omega[1], inertia[2] * omega[2])
    if cross(m, omega) == (0.0, 0.0, 0.0):
        return _steady(omega)
    excess = (momentum_excess(inertia, m, 0), momentum_excess(inertia, m, 1), momentum_excess(inertia, m, 2))
    first, mid, third, sign = circulation_axes(inertia, excess)
    i1, i2, i3 = inertia[first], inertia[mid], inertia[third]
    w1, w2, w3 = sign * omega[first], omega[mid], omega[third]
    d1, d2, d3 = excess[first], excess[mid], excess[third]
    rate2 = (i3 - i2) * d1 / (i1 * i2 * i3)
    if not rate2 > 0.0:
        # moments equal to the last bits: the wobble has no measurable rate
        return _steady(omega)
    a1 = math.copysign(math.sqrt(-d3 / (i1 * (i3 - i1))), w1)
    a2 = math.sqrt(-d3 / (i2 * (i3 - i2)))
    a3 = math.copysign(math.sqrt(d1 / (i3 * (i3 - i1))), w3)
    rate = math.copysign(math.sqrt(rate2), (i3 - i2) * a3 * a1)
    k2 = (i2 - i1) * -d3 / ((i3 - i2) * d1)
    k2c = (i3 - i1) * d2 / ((i3 - i2) * d1)
    n = -i3 * (i2 - i1) / (i1 * (i3 - i2))
    g = math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    coefficient = g * (i3 - i1) / (i1 * i3 * rate)
    sn0, cn0, dn0 = w2 / a2, w1 / a1, w3 / a3
    u0 = first_kind(sn0, cn0, dn0)
    if k2c > 0.0:
        quarter = complete_first(k2c)
        whole = complete_third(n, k2c, quarter)
        period = 4.0 * quarter / abs(rate)
        advance = g / i3 * period + coefficient * math.copysign(4.0 * whole, rate)
        third_start = third_kind(n, sn0, cn0, dn0, u0, whole)
    else:  # on the separatrix: no period
        quarter, whole, period, advance = math.inf, math.inf, math.inf, 0.0
        third_start = _separatrix_third(n, u0)
    return FreeBody(
        False,
        omega,
        first,
        mid,
        third,
        sign,
        i1,
        i2,
        i3,
        a1,
        a2,
        a3,
        rate,
        k2,
        k2c,
        n,
        g,
        coefficient,
        u0,
        third_start,
        quarter,
        whole,
        period,
        advance,
        _tilt(i1, i2, i3, a1, a2, a3, sn0, cn0, dn0),
    )


@jit
def free_motion(body, q, t):
    """The state of a free body a time after a given orientation.

    Parameters
    ----------
    body : FreeBody
        Its constants (`free_body`, from the angular velocity at the same instant as ``q``).
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    t : float
        s, any sign.

    Returns
    -------
    q : tuple of 4 floats
        The orientation after ``t``.
    omega : tuple of 3 floats
        The body angular velocity after ``t`` (rad/s).
    """
    if body.steady:
        return spun_steadily(q, body.omega0, t), body.omega0
    if body.k2c > 0.0:
        periods = math.floor(t / body.period + 0.5)
        tau = t - periods * body.period
        u = body.u0 + body.rate * tau
        turns = math.floor(u / (4.0 * body.quarter) + 0.5)
        u -= 4.0 * body.quarter * turns
        sn, cn, dn = jacobi(u, body.k2, body.k2c, body.quarter)
        third_now = third_kind(body.n, sn, cn, dn, u, body.whole) + 4.0 * body.whole * turns
    else:
        periods, tau = 0.0, t
        u = body.u0 + body.rate * tau
        sn, cn, dn = jacobi(u, 1.0, 0.0, math.inf)
        third_now = _separatrix_third(body.n, u)
    precession = (
        periods * body.advance + body.g / body.i3 * tau + body.coefficient * (third_now - body.third_start)
    )

    half = 0.5 * precession
    relative = quat_mul(
        quat_mul_axis_rotation(quat_conj(body.tilt0), 2, math.sin(half), math.cos(half)),
        _tilt(body.i1, body.i2, body.i3, body.a1, body.a2, body.a3, sn, cn, dn),
    )
    # back to the body's own axes: the vector part of the relative rotation, and w
    vector = [0.0, 0.0, 0.0]
    velocity = [0.0, 0.0, 0.0]
    first, mid, third, sign = body.first, body.mid, body.third, body.sign
    vector[first], vector[mid], vector[third] = sign * relative[0], relative[1], relative[2]
    velocity[first], velocity[mid], velocity[third] = (sign * body.a1 * cn, body.a2 * sn, body.a3 * dn)
    q_t = quat_mul(q, (vector[0], vector[1], vector[2], relative[3]))
    return q_t, (velocity[0], velocity[1], velocity[2])


@jit
def free_flow(inertia, q, omega, t):
    """The exact force-free motion for a time ``t`` (module docstring).

    Parameters
    ----------
    inertia : tuple of 3 floats
        Principal inertias (kg m^2), any order, positive.
    q : tuple of 4 floats
        Orientation (scalar-last, body to space) at the start.
    omega : tuple of 3 floats
        Body angular velocity (rad/s) at the start.
    t : float
        s, any sign.

    Returns
    -------
    q : tuple of 4 floats
        The orientation after ``t``.
    omega : tuple of 3 floats
        The body angular velocity after ``t`` (rad/s).
    """
    return free_motion(free_body(inertia, omega), q, t)


@jit
def free_flow_batch(inertia, quaternion, omega, times, quaternion_out, omega_out):
    """`free_flow` of B bodies from their states at t = 0 to T times each, written in place;
    each body's constants computed once.

    Parameters
    ----------
    inertia : ndarray, shape (B, 3)
        Principal inertias, kg m^2.
    quaternion : ndarray, shape (B, 4)
        Orientations at t = 0 (scalar-last, body to space).
    omega : ndarray, shape (B, 3)
        Body angular velocities at t = 0, rad/s.
    times : ndarray, shape (T,)
        s.
    quaternion_out : ndarray, shape (B, T, 4)
        Written: the orientations.
    omega_out : ndarray, shape (B, T, 3)
        Written: the body angular velocities.
    """
    for b in range(inertia.shape[0]):
        body = free_body(read3(inertia[b], 0), read3(omega[b], 0))
        q0 = read4(quaternion[b], 0)
        for k in range(times.size):
            q_t, w_t = free_motion(body, q0, times[k])
            write4(quaternion_out[b, k], 0, q_t)
            write3(omega_out[b, k], 0, w_t)
