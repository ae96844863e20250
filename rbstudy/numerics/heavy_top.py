"""The exact motion of the Lagrange top: a body symmetric about an axis through the point it
turns about, under a constant space force on that axis (gravity on a top on its pivot).

For a body with principal inertias ``I`` (two equal, ``A``, about the axes across the
symmetry axis ``e_s``; ``C`` about it), orientation ``q`` (body to space), body angular
velocity ``w`` and the moment ``e_s x R^T W`` of a constant space vector ``W`` (N m: the
force times its signed arm along ``e_s``, `rbstudy.numerics.loads`' lever row ``s``), the
potential is ``-W . R e_s = |W| u`` with ``u = z . R e_s`` the cosine of the tilt from
``z = -W / |W|``. The body's ``w_s`` and the momentum's component along ``z`` are kept, as is
the energy, so (docs/theory.md s3; Whittaker, Analytical Dynamics, s71; Goldstein, Classical
Mechanics, s5.7):

1. ``u'^2 = f(u) = (alpha - beta u)(1 - u^2) - (a - b u)^2``, ``beta = 2 |W| / A``,
   ``b = C w_s / A``. Expanded about ``u0`` in ``v = u - u0``, every coefficient is a sum of
   the initial data without the cancellation of the expanded cubic:
   ``g(v) = beta v^3 + c2 v^2 + c1 v + p`` with ``p = u'0^2``,
   ``c1 = -beta sin^2(theta0) - 2 u0 w_t^2 + 2 b h``, ``c2 = 2 beta u0 - w_t^2 - b^2``
   (``w_t`` the spin across the axis, ``h = a - b u0 = z_t . w_t``). Its roots are
   ``v1 <= 0 <= v2 <= v3``: ``v3`` by Newton from Cauchy's bound (``g`` is convex right of
   it), the other two from the deflated quadratic, its coefficients by Vieta.
2. ``u = u0 + v1 cn^2 tau + v2 sn^2 tau``, ``tau = nu t + tau0``, ``nu = sqrt(beta (v3 - v1))
   / 2``, ``k^2 = (v2 - v1) / (v3 - v1)`` and ``k'^2 = (v3 - v2) / (v3 - v1)``;
   ``tau0 = +-F(asin sqrt(-v1 / (v2 - v1)) | k^2)`` with the sign of ``u'0``.
3. The z-x-z angles of the body (precession ``phi`` about ``z``, tilt ``theta``, spin ``psi``
   about ``e_s``) follow from ``phi' = (a - b u) / (1 - u^2)`` and ``psi' = C w_s / C - phi'
   u``, which split into ``1 / (1 - u)`` and ``1 / (1 + u)``; each integrates to Legendre's
   third integral ``Pi(n; am tau | k^2)`` with ``n = +-(v2 - v1) / (1 -+ u1)``:
   ``phi = phi0 + (a - b)/2 I_- + (a + b)/2 I_+`` and
   ``psi = psi0 + (w_s - b) t - (a - b)/2 I_- + (a + b)/2 I_+``, with
   ``I_-+ = [Pi(n_-+; am tau) - Pi(n_-+; am tau0)] / (nu (1 -+ u1))``.
   The orientation is ``R(t) = R0 P B(0)^T Rot(e3, phi - phi0) B(t) P^T``, ``B = Rot(e1, theta)
   Rot(e3, psi)`` and ``P`` the cyclic relabelling that makes ``e_s`` the third axis: no
   frame of ``z`` is built. The body angular velocity is Euler's kinematics of the angles.

Long runs: ``tau`` is reduced to ``|r| <= K`` by whole half periods ``2K``, over each of which
``Pi`` advances by the complete ``2 Pi(n)``, computed once.

Handled: the steady precession (no nutation, ``v1 = v2``), the sleeping top (its axis along
``z`` and no spin across it: a steady spin), ``a = b`` (the force line is a root of ``f``).
Refused (`lagrange_body` gives ``refused`` > 0, and the references integrate instead):
a body whose axis comes within `NEAR_LINE` of the line of the force (``1 -+ u`` below it on
``[u1, u2]``), where the angles lose their meaning and ``w`` its digits.
"""

import math
from collections import namedtuple

from rbstudy.numerics.elliptic import (
    complete_first,
    complete_third_close,
    complete_third_steep,
    first_kind,
    jacobi,
    third_kind_close,
    third_kind_steep,
)
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import (
    norm,
    quat_conj,
    quat_mul,
    quat_mul_axis_rotation,
    quat_rotate_inverse,
    read3,
    read4,
    scale,
    spun_steadily,
    write3,
    write4,
)

__all__ = [
    "LagrangeBody",
    "NEAR_LINE",
    "REFUSALS",
    "lagrange_body",
    "lagrange_motion",
    "lagrange_top_batch",
]

# ``1 - u`` or ``1 + u`` below this somewhere on the motion (the symmetry axis within about
# sqrt(2 NEAR_LINE) = 1e-3 rad of the line of the force) refuses the closed form: ``w`` across
# the axis is a ratio of two quantities that vanish there, and loses eps / sin(theta) of it.
NEAR_LINE = 5e-7
# Why a body is refused: its ``refused`` code - 1 indexes this.
REFUSALS = (
    "its symmetry axis passes within 1e-3 rad of the line of the force, where the z-x-z "
    "angles of the closed form lose their meaning",
)
# Newton's iterations for the largest root (from Cauchy's bound the error halves at worst
# before it converges quadratically: 200 covers any bound a float holds).
_NEWTON_MAX = 200

# The constants of one top (module docstring), in the relabelled frame (``e_s`` third).
# ``refused``: 0, or the code of `REFUSALS`. ``steady``: a sleeping top, spinning at
# ``omega0`` about its axis; the other fields unused. ``spread = u2 - u1``, ``bottom = 1 +
# u1``, ``top = 1 - u2``; ``minus``, ``plus``: the branches of ``1 / (1 -+ u)`` (`_integral`).
LagrangeBody = namedtuple(
    "LagrangeBody",
    [
        "refused",
        "steady",
        "omega0",
        "axis",
        "spread",
        "bottom",
        "top",
        "spin",
        "b",
        "a_minus_b",
        "a_plus_b",
        "rate",
        "k2",
        "k2c",
        "quarter",
        "tau0",
        "minus",
        "plus",
        "psi0",
        "tilt0",
    ],
)


@jit
def _largest_root(beta, c2, c1, p):
    """The largest root of ``beta v^3 + c2 v^2 + c1 v + p`` (``beta > 0``, three real roots),
    by Newton from Cauchy's bound: from the right the cubic is convex, so the iterates fall
    monotonically onto the root and stop when they no longer fall."""
    v = 1.0 + max(abs(c2), abs(c1), abs(p)) / beta
    for _ in range(_NEWTON_MAX):
        value = ((beta * v + c2) * v + c1) * v + p
        slope = (3.0 * beta * v + 2.0 * c2) * v + c1
        if value <= 0.0 or slope <= 0.0:
            break
        step = value / slope
        if not v - step < v:
            break
        v -= step
    return v


@jit
def _roots(beta, b, u0, across, h, slope0, spin_across):
    """The roots ``v1 <= 0 <= v2 <= v3`` of ``g(v) = f(u0 + v)`` (module docstring, step 1)."""
    c1 = -beta * across - 2.0 * u0 * spin_across + 2.0 * b * h
    v3 = _largest_root(beta, 2.0 * beta * u0 - spin_across - b * b, c1, slope0 * slope0)
    # the quadratic v^2 + s v + r of the two small roots: r = v1 v2 = -p / (beta v3), and
    # s = -(v1 + v2) from c1 / beta = v1 v2 + v3 (v1 + v2), both free of the cancellation of
    # c2 / beta + v3
    r = -slope0 * slope0 / (beta * v3)
    s = -(c1 / beta - r) / v3
    root = math.sqrt(max(s * s - 4.0 * r, 0.0))
    big = -0.5 * (s + math.copysign(root, s))
    small = r / big if big != 0.0 else 0.0
    return min(min(big, small), 0.0), max(max(big, small), 0.0), v3  # u0 lies between v1 and v2


@jit
def _pole_distances(beta, b, spin_across, bottom, top, below_one, above_minus_one, a_minus_b, a_plus_b):
    """``1 + u1`` and ``1 - u2`` to their own precision, from their estimates ``bottom`` and
    ``top`` (found about ``u0``, good to an absolute eps): where one is small, by Newton on
    ``f`` expanded about its pole. About ``u = -1`` (``x = 1 + u``) ``f`` is ``beta x^3 - (P +
    2 beta + b^2) x^2 + 2 (P + b (a + b)) x - (a + b)^2``, ``P = w_t^2 + beta (1 + u0)``; about
    ``u = 1`` (``x = 1 - u``) ``-beta x^3 + (2 beta - P' - b^2) x^2 + 2 (P' - b (a - b)) x - (a -
    b)^2``, ``P' = w_t^2 - beta (1 - u0)``."""
    if bottom < 0.25:
        pull = spin_across + beta * above_minus_one
        bottom = _pole_distance(
            bottom, beta, -(pull + 2.0 * beta + b * b), 2.0 * (pull + b * a_plus_b), -a_plus_b * a_plus_b
        )
    if top < 0.25:
        pull = spin_across - beta * below_one
        top = _pole_distance(
            top, -beta, 2.0 * beta - pull - b * b, 2.0 * (pull - b * a_minus_b), -a_minus_b * a_minus_b
        )
    return bottom, top


@jit
def _pole_distance(estimate, c3, c2, c1, c0):
    """The root of ``c3 x^3 + c2 x^2 + c1 x + c0`` next to ``estimate`` >= 0, by Newton: the
    distance ``1 -+ u`` of a turning point from a pole, whose cubic's coefficients (the
    expansion of ``f`` about ``u = -+1``) carry it to its own relative precision when the
    deflated roots, found about ``u0``, hold it only to an absolute eps."""
    x = estimate
    for _ in range(8):
        value = ((c3 * x + c2) * x + c1) * x + c0
        slope = (3.0 * c3 * x + 2.0 * c2) * x + c1
        if slope == 0.0:
            break
        step = value / slope
        if step == 0.0 or not abs(step) < abs(x) + 1.0:
            break
        x -= step
    return x if x >= 0.0 else estimate


@jit
def _reduced(tau, k2, k2c, quarter):
    """``tau`` reduced by whole half periods ``2K`` to ``|r| <= K``: ``(turns, r, sn, cn,
    dn)``, Jacobi's functions of ``r``, which both branches and ``u`` read."""
    turns = math.floor(tau / (2.0 * quarter) + 0.5)
    r = tau - 2.0 * quarter * turns
    sn, cn, dn = jacobi(r, k2, k2c, quarter)
    return turns, r, sn, cn, dn


@jit
def _third(n, n1, k2, whole, at):
    """``Pi(n; am tau | k^2)`` for any ``tau`` (``n1 = 1 - n``; ``at``: `_reduced` of
    ``tau``); for ``n < 0`` the form that keeps its digits as ``n -> -inf``, else the one that
    keeps them as ``n -> 1`` (a turning point next to either pole)."""
    turns, r, sn, cn, dn = at
    if n < 0.0:
        reduced = third_kind_steep(n, sn, cn, dn, r, k2, whole)
    else:
        reduced = third_kind_close(n, n1, sn, cn, dn, r, whole)
    return reduced + 2.0 * whole * turns


@jit
def _tilt(theta_sin, theta_cos, psi):
    """The quaternion of ``B = Rot(e1, theta) Rot(e3, psi)``."""
    theta = math.atan2(theta_sin, theta_cos)
    tilt = (math.sin(0.5 * theta), 0.0, 0.0, math.cos(0.5 * theta))
    return quat_mul_axis_rotation(tilt, 2, math.sin(0.5 * psi), math.cos(0.5 * psi))


@jit
def _without_nutation(refused, steady, omega):
    """A top refused (``refused`` its code) or sleeping (``steady``: spinning at ``omega``
    about its axis): the fields of the elliptic motion unused."""
    unused = (0.0, 0.0, 0.0, 0.0, 0.0)
    return LagrangeBody(
        refused,
        steady,
        omega,
        0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
        0.0,
        unused,
        unused,
        0.0,
        (0.0, 0.0, 0.0, 1.0),
    )


@jit
def _branch(n, n1, k2, k2c, quarter, tau0, offset):
    """A branch of `_integral`: ``(n, 1 - n, Pi(n), Pi(n; am tau0), offset)``."""
    whole = complete_third_steep(n, k2, k2c) if n < 0.0 else complete_third_close(n, n1, k2c, quarter)
    return n, n1, whole, _third(n, n1, k2, whole, _reduced(tau0, k2, k2c, quarter)), offset


# longer than the limit: one top's constants, twenty fields built in one call
@jit
def lagrange_body(inertia, axis, q, omega, arm_force):
    """The constants of a Lagrange top's motion (module docstring).

    Parameters
    ----------
    inertia : tuple of 3 floats
        Principal inertias about the fixed point (kg m^2), the two across ``axis`` equal.
    axis : int
        The symmetry axis ``s`` (0, 1, 2).
    q : tuple of 4 floats
        Orientation at t = 0 (scalar last, body to space).
    omega : tuple of 3 floats
        Body angular velocity at t = 0 (rad/s).
    arm_force : tuple of 3 floats
        ``W``, N m: the space force times its signed arm along the axis; not zero.

    Returns
    -------
    LagrangeBody
    """
    first, second = (axis + 1) % 3, (axis + 2) % 3
    transverse, axial = inertia[first], inertia[axis]
    weight = norm(arm_force)
    up = quat_rotate_inverse(q, scale(-1.0 / weight, arm_force))  # z in body axes
    z1, z2, u0 = up[first], up[second], up[axis]
    w1, w2, spin = omega[first], omega[second], omega[axis]
    across = z1 * z1 + z2 * z2  # sin^2 theta0
    if across == 0.0 and w1 == 0.0 and w2 == 0.0:
        return _without_nutation(0, True, omega)  # sleeping: a steady spin
    beta = 2.0 * weight / transverse
    b = axial * spin / transverse
    h = z1 * w1 + z2 * w2  # a - b u0
    slope0 = z1 * w2 - z2 * w1  # u'(0)
    spin_across = w1 * w1 + w2 * w2
    # 1 -+ u0, each without cancellation, and a -+ b
    below_one = across / (1.0 + u0) if u0 > 0.0 else 1.0 - u0
    above_minus_one = across / (1.0 - u0) if u0 < 0.0 else 1.0 + u0
    a_minus_b, a_plus_b = h - b * below_one, h + b * above_minus_one
    v1, v2, v3 = _roots(beta, b, u0, across, h, slope0, spin_across)
    bottom, top = _pole_distances(
        beta,
        b,
        spin_across,
        above_minus_one + v1,
        below_one - v2,
        below_one,
        above_minus_one,
        a_minus_b,
        a_plus_b,
    )
    if bottom <= 0.0 or top <= 0.0:
        return _without_nutation(1, False, omega)
    spread, span = v2 - v1, v3 - v1
    k2, k2c = spread / span, (v3 - v2) / span
    rate = 0.5 * math.sqrt(beta * span)
    quarter = complete_first(k2c)
    if spread > 0.0:
        sn0, cn0 = math.sqrt(-v1 / spread), math.sqrt(v2 / spread)
        tau0 = math.copysign(first_kind(sn0, cn0, math.sqrt(cn0 * cn0 + k2c * sn0 * sn0)), slope0)
    else:
        tau0 = 0.0  # steady precession: u stays u0
    psi0 = math.atan2(z1, z2)
    return LagrangeBody(
        0,
        False,
        omega,
        axis,
        spread,
        bottom,
        top,
        spin,
        b,
        a_minus_b,
        a_plus_b,
        rate,
        k2,
        k2c,
        quarter,
        tau0,
        _branch(spread / (top + spread), top / (top + spread), k2, k2c, quarter, tau0, top + spread),
        _branch(-spread / bottom, (bottom + spread) / bottom, k2, k2c, quarter, tau0, bottom),
        psi0,
        _tilt(math.sqrt(across), u0, psi0),
    )


@jit
def _integral(top, branch, at):
    """``int_0^t dt / (1 -+ u)`` of one ``branch`` ``(n, 1 - n, Pi(n), Pi(n; am tau0), 1 -+
    u1)`` at ``tau = rate t + tau0`` (``at``: `_reduced` of ``tau``)."""
    n, n1, whole, start, offset = branch
    return (_third(n, n1, top.k2, whole, at) - start) / (top.rate * offset)


@jit
def lagrange_motion(top, q, t):
    """The state of a Lagrange top a time ``t`` after the orientation ``q`` its constants
    were taken at.

    Parameters
    ----------
    top : LagrangeBody
        Its constants (`lagrange_body`), not refused.
    q : tuple of 4 floats
        Orientation at t = 0 (scalar last, body to space).
    t : float
        s.

    Returns
    -------
    q : tuple of 4 floats
        The orientation at ``t``.
    omega : tuple of 3 floats
        The body angular velocity at ``t`` (rad/s).
    """
    if top.steady:
        return spun_steadily(q, top.omega0, t), top.omega0
    at = _reduced(top.rate * t + top.tau0, top.k2, top.k2c, top.quarter)  # once for u and both branches
    sn, cn, dn = at[2], at[3], at[4]
    above = top.bottom + top.spread * sn * sn  # 1 + u
    below = top.top + top.spread * cn * cn  # 1 - u
    across = math.sqrt(below * above)  # sin theta
    minus = _integral(top, top.minus, at)
    plus = _integral(top, top.plus, at)
    precession = 0.5 * (top.a_minus_b * minus + top.a_plus_b * plus)
    psi = top.psi0 + (top.spin - top.b) * t + 0.5 * (top.a_plus_b * plus - top.a_minus_b * minus)
    tilt = _tilt(across, 0.5 * (above - below), psi)
    half = 0.5 * precession
    relative = quat_mul(quat_mul_axis_rotation(quat_conj(top.tilt0), 2, math.sin(half), math.cos(half)), tilt)
    # Euler's kinematics: w1 = phi' sin(theta) sin(psi) + theta' cos(psi), w2 = phi' sin(theta)
    # cos(psi) - theta' sin(psi), with phi' sin(theta) = (a - b u) / sin(theta), a - b u taken
    # from the nearer pole, and theta' = -u' / sin(theta)
    leaning = top.a_plus_b - top.b * above if above < below else top.a_minus_b + top.b * below
    lean = leaning / across
    nod = -2.0 * top.rate * top.spread * sn * cn * dn / across
    sp, cp = math.sin(psi), math.cos(psi)
    first, second, axis = (top.axis + 1) % 3, (top.axis + 2) % 3, top.axis
    vector = [0.0, 0.0, 0.0]
    velocity = [0.0, 0.0, 0.0]
    vector[first], vector[second], vector[axis] = relative[0], relative[1], relative[2]
    velocity[first], velocity[second], velocity[axis] = lean * sp + nod * cp, lean * cp - nod * sp, top.spin
    return quat_mul(q, (vector[0], vector[1], vector[2], relative[3])), (
        velocity[0],
        velocity[1],
        velocity[2],
    )


@jit
def lagrange_top_batch(
    inertia, axes, quaternion, omega, arm_force, times, quaternion_out, omega_out, refused
):
    """`lagrange_motion` of B tops from their states at t = 0 to T times each, written in
    place; each top's constants computed once.

    Parameters
    ----------
    inertia : ndarray, shape (B, 3)
        Principal inertias about the fixed point, kg m^2.
    axes : ndarray, shape (B,), int
        Each body's symmetry axis.
    quaternion : ndarray, shape (B, 4)
        Orientations at t = 0.
    omega : ndarray, shape (B, 3)
        Body angular velocities at t = 0, rad/s.
    arm_force : ndarray, shape (B, 3)
        ``W`` of each top, N m.
    times : ndarray, shape (T,)
        s.
    quaternion_out : ndarray, shape (B, T, 4)
        Written: the orientations (left alone for a refused top).
    omega_out : ndarray, shape (B, T, 3)
        Written: the body angular velocities.
    refused : ndarray, shape (B,), int
        Written: 0, or the code of `REFUSALS` of a top the closed form does not take.
    """
    for b in range(inertia.shape[0]):
        top = lagrange_body(
            read3(inertia[b], 0), axes[b], read4(quaternion[b], 0), read3(omega[b], 0), read3(arm_force[b], 0)
        )
        refused[b] = top.refused
        if top.refused:
            continue
        q0 = read4(quaternion[b], 0)
        for k in range(times.size):
            q, w = lagrange_motion(top, q0, times[k])
            write4(quaternion_out[b, k], 0, q)
            write3(omega_out[b, k], 0, w)
