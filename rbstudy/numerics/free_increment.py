"""The exact free flow over a short time as an increment of the state, each component to its
own relative accuracy: what compensated summation (`rbstudy.numerics.compensated`) needs to
add the flow of `rbstudy.numerics.free_flow` without an ulp of the state per step.

`free_flow.free_motion` evaluates the state after a time ``h`` afresh: ``w`` from ``cn, sn,
dn`` of ``u0 + lambda h``, and the rotation as a product of rotations of order one that
nearly cancel. Its results are good to an ulp of the state, so ``new - old`` carries that ulp
however short the step. Here every quantity is a difference from the start, written without
cancellation (docs/theory.md s8), in the relabelled frame of `free_flow` (``v = lambda h``,
``(s, c, d)`` Jacobi's functions of ``v``, and at the start ``sn0 = w2 / a2`` and so on):

1. the spin, by the addition theorems (DLMF 22.8.1-3) less the start, with
   ``D = 1 - k^2 sn0^2 s^2``, ``c - 1 = -s^2 / (1 + c)``, ``d - 1 = -k^2 s^2 / (1 + d)``:
   ``D dsn = sn0 (c d - 1 + k^2 sn0^2 s^2) + cn0 dn0 s``,
   ``D dcn = cn0 (c - 1 + k^2 sn0^2 s^2) - sn0 dn0 s d``,
   ``D ddn = dn0 (d - 1 + k^2 sn0^2 s^2) - k^2 sn0 cn0 s c``;
2. the body's rotation ``r = B0^T Rot(e3, dphi) B(h)`` as ``A C Z``: ``A`` the turn by
   ``dphi`` about ``B0^T e3 = m0 / G``, ``C`` the turn by ``dtheta`` about ``Rot(e3,
   psi0)^T e1`` and ``Z = Rot(e3, dpsi)``, since ``B = Rot(e1, theta) Rot(e3, psi)``; the
   angle differences are ``atan2`` of the cross and dot products of the start and end
   vectors, the cross product taken from the increments; ``r - 1`` is composed from each
   factor's ``f - 1`` (``(x y) - 1 = (x - 1)(y - 1) + (x - 1) + (y - 1)``);
3. ``dphi = G h / I3 + G (I3 - I1) / (I1 I3 lambda) dPi``, with ``dPi = int_u0^(u0 + v)
   du / (1 - n sn^2 u)`` by Gauss-Legendre quadrature, ``sn`` at the nodes again by the
   addition theorem from the start. For a rigid body ``n < 0``: the integrand lies in
   ``(1 / (1 - n), 1]``, and its poles nearest the real axis, at ``sn^2 = 1 / n``, are at
   least ``1 / sqrt(1 - n)`` from it (``sn(iy) = i sc(y | 1 - k^2)``, ``sc y <= tan y``), so
   panels of `PANEL_SPAN` times that width make the quadrature exact to rounding.
   The sign of ``q`` stays continuous (``free_motion`` may return ``-q`` where its angle
   ``psi`` wraps), as increments must.

A step longer than a quarter period of the wobble (``|v| > K``), where Jacobi's functions of
``v`` are not at hand, falls back to the difference of `free_motion`'s states: the step is
as accurate as before, and compensation gains nothing there.
"""

import math

import numpy as np

from rbstudy.numerics.elliptic import jacobi
from rbstudy.numerics.free_flow import free_motion
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import (
    cos_minus_one,
    quat_exp_minus_one,
    quat_mul,
    quat_rotate_inverse,
)

__all__ = ["free_increment", "PANEL_SPAN", "NODES"]

# Gauss-Legendre nodes per panel, and the panel's width as a fraction of the poles' least
# distance from the real axis, y: 8 nodes on a panel of half-width L converge as rho^-16,
# rho = y/L + sqrt(1 + (y/L)^2) (the Bernstein ellipse through the pole; Trefethen,
# Approximation Theory and Approximation Practice, ch. 19), and y/L = 2 / 0.35 gives
# rho = 11.5 and rho^-16 = 1e-17 (checked against `third_kind` on random bodies with
# n down to -1e3, tests/test_free_increment.py).
NODES = 8
PANEL_SPAN = 0.35
_X, _W = np.polynomial.legendre.leggauss(NODES)
_NODE_AT = 0.5 * (_X + 1.0)  # on [0, 1]
_WEIGHT = 0.5 * _W


@jit
def _minus_one(axis, s, c):
    """``f - 1`` for the unit quaternion ``f = (s axis, c)`` of a turn about the unit ``axis``
    by the angle whose half has sine ``s`` and cosine ``c``."""
    return (s * axis[0], s * axis[1], s * axis[2], cos_minus_one(s, c))


@jit
def _compose_minus_one(x, y):
    """``x y - 1`` from ``x - 1`` and ``y - 1`` (quaternions, scalar last)."""
    xy = quat_mul(x, y)
    return (xy[0] + x[0] + y[0], xy[1] + x[1] + y[1], xy[2] + x[2] + y[2], xy[3] + x[3] + y[3])


@jit
def _turn_minus_one(axis, angle):
    """``f - 1`` of the turn by ``angle`` about the unit ``axis``."""
    return _minus_one(axis, math.sin(0.5 * angle), math.cos(0.5 * angle))


@jit
def _angle_between(x0, y0, dx, dy):
    """The angle from the 2-vector ``(x0, y0)`` to ``(x0 + dx, y0 + dy)``, its sine part from
    the increments (no cancellation)."""
    return math.atan2(x0 * dy - y0 * dx, x0 * (x0 + dx) + y0 * (y0 + dy))


@jit
def _shifted_sn(body, sn0, cn0, dn0, v):
    """``sn(u0 + v)`` by the addition theorem from Jacobi's functions at ``u0``."""
    s, c, d = jacobi(v, body.k2, body.k2c, body.quarter)
    return (sn0 * c * d + cn0 * dn0 * s) / (1.0 - body.k2 * sn0 * sn0 * s * s)


@jit
def _third_increment(body, sn0, cn0, dn0, v):
    """``Pi(n; am(u0 + v)) - Pi(n; am u0)`` by Gauss-Legendre quadrature (module docstring)."""
    panels = max(1, math.ceil(abs(v) * math.sqrt(1.0 - body.n) / PANEL_SPAN))
    width = v / panels
    total = 0.0
    for panel in range(panels):
        for j in range(NODES):
            sn = _shifted_sn(body, sn0, cn0, dn0, width * (panel + _NODE_AT[j]))
            total += _WEIGHT[j] / (1.0 - body.n * sn * sn)
    return width * total


@jit
def free_increment(body, q, h):
    """The exact force-free motion over ``h`` as increments of the orientation and the spin.

    Parameters
    ----------
    body : FreeBody
        The constants (`rbstudy.numerics.free_flow.free_body`) of the spin at the start.
    q : tuple of 4 floats
        Orientation at the start, scalar last, body to space.
    h : float
        s, any sign.

    Returns
    -------
    dq : tuple of 4 floats
        ``q(h) - q`` as ``q (r - 1)``, ``r - 1`` to its own accuracy; ``q + dq`` is unit to
        the truncation of nothing, an ulp or so (the caller renormalises).
    dw : tuple of 3 floats
        ``w(h) - w`` (rad/s).
    """
    omega = body.omega0
    if body.steady:
        return quat_mul(q, quat_exp_minus_one((omega[0] * h, omega[1] * h, omega[2] * h))), (0.0, 0.0, 0.0)
    v = body.rate * h
    if abs(v) > body.quarter:
        q_h, w_h = free_motion(body, q, h)
        return (
            (q_h[0] - q[0], q_h[1] - q[1], q_h[2] - q[2], q_h[3] - q[3]),
            (w_h[0] - omega[0], w_h[1] - omega[1], w_h[2] - omega[2]),
        )
    first, mid, third, sign = body.first, body.mid, body.third, body.sign
    i1, i2, i3, a1, a2, a3, k2 = body.i1, body.i2, body.i3, body.a1, body.a2, body.a3, body.k2
    sn0, cn0, dn0 = omega[mid] / a2, sign * omega[first] / a1, omega[third] / a3
    s, c, d = jacobi(v, k2, body.k2c, body.quarter)
    c1 = -s * s / (1.0 + c)
    d1 = -k2 * s * s / (1.0 + d)
    shear = k2 * sn0 * sn0 * s * s
    denominator = 1.0 - shear
    dsn = (sn0 * (c1 * d1 + c1 + d1 + shear) + cn0 * dn0 * s) / denominator
    dcn = (cn0 * (c1 + shear) - sn0 * dn0 * s * d) / denominator
    ddn = (dn0 * (d1 + shear) - k2 * sn0 * cn0 * s * c) / denominator

    # theta: the tilt of m from e3, from (m3, |(m1, m2)|)
    x0, y0 = i1 * a1 * cn0, i2 * a2 * sn0
    dx, dy = i1 * a1 * dcn, i2 * a2 * dsn
    rho0 = math.hypot(x0, y0)
    rho1 = math.hypot(x0 + dx, y0 + dy)
    drho = ((2.0 * x0 + dx) * dx + (2.0 * y0 + dy) * dy) / (rho0 + rho1) if rho0 + rho1 > 0.0 else 0.0
    dtheta = _angle_between(i3 * a3 * dn0, rho0, i3 * a3 * ddn, drho)
    # psi, as free_flow._tilt takes it from (sn, cn)
    p = math.copysign(math.sqrt(i1 * abs(i3 - i2)), a1)
    r = math.sqrt(i2 * abs(i3 - i1))
    psi0 = math.atan2(p * cn0, r * sn0)
    dpsi = _angle_between(r * sn0, p * cn0, r * dsn, p * dcn)
    dphi = body.g / i3 * h + body.coefficient * _third_increment(body, sn0, cn0, dn0, v)

    spin_axis = quat_rotate_inverse(body.tilt0, (0.0, 0.0, 1.0))
    tilt_axis = (math.cos(psi0), -math.sin(psi0), 0.0)
    rotation = _compose_minus_one(
        _turn_minus_one(spin_axis, dphi),
        _compose_minus_one(_turn_minus_one(tilt_axis, dtheta), _turn_minus_one((0.0, 0.0, 1.0), dpsi)),
    )
    # back to the body's own axes
    vector = [0.0, 0.0, 0.0]
    spin = [0.0, 0.0, 0.0]
    vector[first], vector[mid], vector[third] = sign * rotation[0], rotation[1], rotation[2]
    spin[first], spin[mid], spin[third] = sign * a1 * dcn, a2 * dsn, a3 * ddn
    dq = quat_mul(q, (vector[0], vector[1], vector[2], rotation[3]))
    return dq, (spin[0], spin[1], spin[2])
