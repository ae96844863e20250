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

Permanent rotations (``m x w = 0``: about a principal axis, any axis of a spherical body, an
axis in the plane of equal moments of a symmetric one) turn at constant ``w``. The
separatrix (``k' = 0``) takes ``sn = tanh``, ``cn = dn = sech`` and the closed form
``Pi(n; am u | 1) = (u + sqrt(a) atan(sqrt(a) tanh u)) / (1 + a)``, ``a = -n``.
"""

import math

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
    quat_exp,
    quat_mul,
    quat_mul_axis_rotation,
    read3,
    read4,
    write3,
    write4,
)

__all__ = ["free_flow", "free_flow_batch"]


@jit
def _excess(inertia, m, j):
    """``G^2 - 2 E I_j = sum_{n != j} m_n^2 (I_n - I_j) / I_n``, term by term."""
    total = 0.0
    for k in range(3):
        if k != j:
            total += m[k] * m[k] * (inertia[k] - inertia[j]) / inertia[k]
    return total


@jit
def _sorted_axes(inertia):
    """Indices of the smallest, intermediate and largest principal moment."""
    lo, mid, hi = 0, 1, 2
    if inertia[lo] > inertia[mid]:
        lo, mid = mid, lo
    if inertia[mid] > inertia[hi]:
        mid, hi = hi, mid
    if inertia[lo] > inertia[mid]:
        lo, mid = mid, lo
    return lo, mid, hi


@jit
def _permanent(q, omega, t):
    """Rotation at constant ``omega`` about a fixed axis."""
    turn = (omega[0] * t, omega[1] * t, omega[2] * t)
    return quat_mul(q, quat_exp(turn)), omega


@jit
def _tilt(i1, i2, i3, a1, a2, a3, sn, cn, dn):
    """The quaternion of ``B = Rot(e1, theta) Rot(e3, psi)``, which takes ``m`` to ``G e3``,
    in the relabelled frame."""
    theta = math.atan2(math.hypot(i1 * a1 * cn, i2 * a2 * sn), i3 * a3 * dn)
    psi = math.atan2(math.copysign(math.sqrt(i1 * abs(i3 - i2)), a1) * cn,
                     math.sqrt(i2 * abs(i3 - i1)) * sn)
    tilt = (math.sin(0.5 * theta), 0.0, 0.0, math.cos(0.5 * theta))
    return quat_mul_axis_rotation(tilt, 2, math.sin(0.5 * psi), math.cos(0.5 * psi))


@jit
def free_flow(inertia, q, omega, t):
    """The exact force-free motion for a time ``t`` (module docstring).

    Parameters
    ----------
    inertia : 3-tuple, principal inertias (kg m^2), any order, positive.
    q : 4-tuple, orientation (scalar-last, body to space) at the start.
    omega : 3-tuple, body angular velocity (rad/s) at the start.
    t : float, s (any sign).

    Returns
    -------
    (q, omega) after ``t``: a 4-tuple and a 3-tuple.
    """
    m = (inertia[0] * omega[0], inertia[1] * omega[1], inertia[2] * omega[2])
    if cross(m, omega) == (0.0, 0.0, 0.0):
        return _permanent(q, omega, t)
    lo, mid, hi = _sorted_axes(inertia)
    d2 = _excess(inertia, m, mid)
    first, third = (lo, hi) if d2 > 0.0 else (hi, lo)
    # the relabelled axes (first, mid, third), the first negated if that order is odd
    s1 = 1.0 if mid == (first + 1) % 3 else -1.0
    i1, i2, i3 = inertia[first], inertia[mid], inertia[third]
    w1, w2, w3 = s1 * omega[first], omega[mid], omega[third]
    d1, d3 = _excess(inertia, m, first), _excess(inertia, m, third)
    rate2 = (i3 - i2) * d1 / (i1 * i2 * i3)
    if not rate2 > 0.0:
        # moments equal to the last bits: the wobble has no measurable rate
        return _permanent(q, omega, t)
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
        periods = math.floor(t / period + 0.5)
        tau = t - periods * period
        advance = g / i3 * period + coefficient * math.copysign(4.0 * whole, rate)
        u = u0 + rate * tau
        turns = math.floor(u / (4.0 * quarter) + 0.5)
        u -= 4.0 * quarter * turns
        sn, cn, dn = jacobi(u, k2, k2c, quarter)
        third_now = third_kind(n, sn, cn, dn, u, whole) + 4.0 * whole * turns
        third_start = third_kind(n, sn0, cn0, dn0, u0, whole)
    else:  # on the separatrix: no period
        periods, advance, tau = 0.0, 0.0, t
        u = u0 + rate * tau
        sn, cn, dn = jacobi(u, 1.0, 0.0, math.inf)
        a = -n
        third_now = (u + math.sqrt(a) * math.atan(math.sqrt(a) * math.tanh(u))) / (1.0 + a)
        third_start = (u0 + math.sqrt(a) * math.atan(math.sqrt(a) * math.tanh(u0))) / (1.0 + a)
    precession = periods * advance + g / i3 * tau + coefficient * (third_now - third_start)

    half = 0.5 * precession
    relative = quat_mul(
        quat_mul_axis_rotation(quat_conj(_tilt(i1, i2, i3, a1, a2, a3, sn0, cn0, dn0)), 2,
                               math.sin(half), math.cos(half)),
        _tilt(i1, i2, i3, a1, a2, a3, sn, cn, dn))
    # back to the body's own axes: the vector part of the relative rotation, and w
    vector = [0.0, 0.0, 0.0]
    velocity = [0.0, 0.0, 0.0]
    vector[first], vector[mid], vector[third] = s1 * relative[0], relative[1], relative[2]
    velocity[first], velocity[mid], velocity[third] = s1 * a1 * cn, a2 * sn, a3 * dn
    q_t = quat_mul(q, (vector[0], vector[1], vector[2], relative[3]))
    return q_t, (velocity[0], velocity[1], velocity[2])


@jit
def free_flow_batch(inertia, quaternion, omega, times, quaternion_out, omega_out):
    """`free_flow` of B bodies from their states at t = 0 to T times each, written in place.

    Parameters
    ----------
    inertia : (B, 3) principal inertias, kg m^2.
    quaternion : (B, 4) orientations at t = 0 (scalar-last, body to space).
    omega : (B, 3) body angular velocities at t = 0, rad/s.
    times : (T,) s.
    quaternion_out : (B, T, 4), written.
    omega_out : (B, T, 3), written.
    """
    for b in range(inertia.shape[0]):
        body = read3(inertia[b], 0)
        q0 = read4(quaternion[b], 0)
        w0 = read3(omega[b], 0)
        for k in range(times.size):
            q_t, w_t = free_flow(body, q0, w0, times[k])
            write4(quaternion_out[b, k], 0, q_t)
            write3(omega_out[b, k], 0, w_t)

