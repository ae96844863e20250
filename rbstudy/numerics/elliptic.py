"""Elliptic integrals and Jacobi elliptic functions as scalar kernels, for the exact flow of
the free rigid body (`rbstudy.numerics.free_flow`).

Every function takes the parameter ``m = k^2`` together with its complement ``m1 = 1 - m``,
which the caller computes without cancellation: near the separatrix of the free body
``m1`` is 1e-12 or smaller, and ``1 - m`` would keep none of its digits. scipy's ``ellipj``
takes ``m`` alone and loses accuracy as ``m -> 1`` (scipy issue 8480); here nothing is ever
formed as ``1 - m``.

- Carlson's symmetric integrals ``R_F``, ``R_J`` by duplication (B. C. Carlson, "Numerical
  computation of real or complex elliptic integrals", Numer. Algorithms 10 (1995) 13-26,
  algorithms 1 and 4, with his fifth-order series): Legendre's integrals of the first and
  third kind, complete and incomplete, follow from them (DLMF 19.25).
- Jacobi's ``sn, cn, dn`` by the arithmetic-geometric mean and the descending Landen
  (Gauss) transformation (Abramowitz and Stegun 16.4), on the half of a quarter period next
  to 0. On the other half (``K/2 < v <= K``) they come from ``K - v`` through the quarter-
  period shift (DLMF 22.4.3): ``sn v = cd(K - v)``, ``cn v = k' sd(K - v)``,
  ``dn v = k' nd(K - v)``. So ``cn`` and ``dn`` keep their relative accuracy where they are
  small (next to ``K`` when ``m1`` is small), and the third-kind integral, evaluated from
  them, keeps its absolute accuracy there; evaluated from the amplitude ``am v`` instead it
  lost up to ``eps / sqrt(k')``.
"""

import math

import numpy as np

from rbstudy.numerics.jit import jit

__all__ = [
    "carlson_rf",
    "carlson_rj",
    "complete_first",
    "complete_third",
    "jacobi",
    "third_kind",
    "third_kind_steep",
    "complete_third_steep",
    "third_kind_close",
    "complete_third_close",
    "first_kind",
]

# The duplication stops when the spread of the arguments is below this fraction of their
# mean (Carlson 1995: the relative error of the fifth-order series is then below
# ~ TOLERANCE^6 / (4 (1 - TOLERANCE))), which is 1e-16 for 2.0e-3 (R_F) and 1.5e-3 (R_J).
RF_TOLERANCE = 2.0e-3
RJ_TOLERANCE = 1.5e-3
# The arithmetic-geometric mean of (1, k') has converged to double precision when
# c_n / a_n is below this; it takes at most 8 steps for k' >= 1e-150 (quadratic convergence
# after log2(ln(4 / k')) steps), 16 leaves room for any normal k'.
AGM_TOLERANCE = 1e-16
AGM_MAX_STEPS = 16


@jit
def carlson_rf(x, y, z):
    """Carlson's ``R_F(x, y, z) = 1/2 int_0^inf dt / sqrt((t + x)(t + y)(t + z))`` (Carlson
    1995, algorithm 1).

    Parameters
    ----------
    x, y, z : float
        >= 0, at most one of them zero.

    Returns
    -------
    float
    """
    mean = (x + y + z) / 3.0
    while True:
        spread = max(abs(mean - x), abs(mean - y), abs(mean - z))
        if spread <= RF_TOLERANCE * abs(mean):
            break
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * sy + sy * sz + sz * sx
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
        mean = 0.25 * (mean + lam)
    dx, dy = (mean - x) / mean, (mean - y) / mean
    dz = -dx - dy
    e2 = dx * dy - dz * dz
    e3 = dx * dy * dz
    return (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0) / math.sqrt(mean)


@jit
def _carlson_rc_one(e):
    """``R_C(1, 1 + e)`` for ``e > -1``: ``atan(sqrt(e))/sqrt(e)``, ``atanh(sqrt(-e))/sqrt(-e)``
    below zero (DLMF 19.2.18-19.2.19)."""
    if e > 0.0:
        s = math.sqrt(e)
        return math.atan(s) / s
    if e < 0.0:
        s = math.sqrt(-e)
        return math.atanh(s) / s
    return 1.0


@jit
def carlson_rj(x, y, z, p):
    """Carlson's ``R_J(x, y, z, p) = 3/2 int_0^inf dt / ((t + p) sqrt((t + x)(t + y)(t + z)))``
    (Carlson 1995, algorithm 4).

    Parameters
    ----------
    x, y, z : float
        >= 0, at most one of them zero.
    p : float
        > 0.

    Returns
    -------
    float
    """
    mean = (x + y + z + 2.0 * p) / 5.0
    mean0, x0, y0, z0 = mean, x, y, z
    delta = (p - x) * (p - y) * (p - z)
    scale = 1.0
    total = 0.0
    while True:
        spread = max(abs(mean - x), abs(mean - y), abs(mean - z), abs(mean - p))
        if spread <= RJ_TOLERANCE * abs(mean):
            break
        sx, sy, sz, sp = math.sqrt(x), math.sqrt(y), math.sqrt(z), math.sqrt(p)
        lam = sx * sy + sy * sz + sz * sx
        d = (sp + sx) * (sp + sy) * (sp + sz)
        e = delta * scale**3 / (d * d)
        total += scale * _carlson_rc_one(e) / d
        x, y, z, p = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam), 0.25 * (p + lam)
        mean = 0.25 * (mean + lam)
        scale *= 0.25
    dx = (mean0 - x0) * scale / mean
    dy = (mean0 - y0) * scale / mean
    dz = (mean0 - z0) * scale / mean
    dp = -0.5 * (dx + dy + dz)
    e2 = dx * dy + dx * dz + dy * dz - 3.0 * dp * dp
    e3 = dx * dy * dz + 2.0 * e2 * dp + 4.0 * dp**3
    e4 = (2.0 * dx * dy * dz + e2 * dp + 3.0 * dp**3) * dp
    e5 = dx * dy * dz * dp * dp
    series = (
        1.0
        - 3.0 * e2 / 14.0
        + e3 / 6.0
        + 9.0 * e2 * e2 / 88.0
        - 3.0 * e4 / 22.0
        - 9.0 * e2 * e3 / 52.0
        + 3.0 * e5 / 26.0
    )
    return scale * series / (mean * math.sqrt(mean)) + 6.0 * total


@jit
def complete_first(m1):
    """``K(m) = R_F(0, m1, 1)``, the quarter period.

    Parameters
    ----------
    m1 : float
        The complementary parameter ``1 - m``, > 0.

    Returns
    -------
    float
    """
    return carlson_rf(0.0, m1, 1.0)


@jit
def complete_third(n, m1, quarter):
    """``Pi(n | m) = K + n/3 R_J(0, m1, 1, 1 - n)``.

    Parameters
    ----------
    n : float
        The characteristic, < 1.
    m1 : float
        The complementary parameter ``1 - m``, > 0.
    quarter : float
        ``K(m)`` (`complete_first`).

    Returns
    -------
    float
    """
    return quarter + n / 3.0 * carlson_rj(0.0, m1, 1.0, 1.0 - n)


@jit
def first_kind(s, c, d):
    """``F(phi | m) = s R_F(c^2, d^2, 1)`` for ``|phi| <= pi/2`` (DLMF 19.25.5).

    Parameters
    ----------
    s, c : float
        ``sin phi`` and ``cos phi >= 0``.
    d : float
        ``sqrt(1 - m sin^2 phi)``.

    Returns
    -------
    float
    """
    return s * carlson_rf(c * c, d * d, 1.0)


@jit
def _reflected(reduced, cn, u, complete):
    """``Pi(n; am u)`` from the integral ``reduced`` up to the angle ``asin(sn u)``: itself
    where ``cn >= 0``, else ``Pi(n; pi - phi) = 2 Pi(n) - Pi(n; phi)`` (signed as ``u``)."""
    if cn >= 0.0:
        return reduced
    return math.copysign(2.0 * complete, u) - reduced


@jit
def third_kind(n, sn, cn, dn, u, complete):
    """Legendre's ``Pi(n; am u | m) = int_0^u dv / (1 - n sn^2 v)`` for ``|u| <= 2K``, from ``sn
    u, cn u, dn u`` (DLMF 19.25.14 on the angle ``asin(sn)``, and ``Pi(n; pi - phi) = 2 Pi(n) -
    Pi(n; phi)`` where ``cn < 0``).

    Parameters
    ----------
    n : float
        The characteristic, < 1.
    sn, cn, dn : float
        Jacobi's functions of ``u`` (`jacobi`).
    u : float
        The argument, ``|u| <= 2K``.
    complete : float
        ``Pi(n | m)`` (`complete_third`); unused where ``cn >= 0``, so it may be inf on the
        separatrix.

    Returns
    -------
    float
    """
    s2 = sn * sn
    reduced = sn * carlson_rf(cn * cn, dn * dn, 1.0) + n / 3.0 * sn * s2 * carlson_rj(
        cn * cn, dn * dn, 1.0, 1.0 - n * s2
    )
    return _reflected(reduced, cn, u, complete)


@jit
def _steep_reduced(n, m, s, c, d):
    """``Pi(n; phi | m)`` for ``n < 0``, ``|phi| <= pi/2`` (``s, c, d = sin phi, cos phi >= 0,
    sqrt(1 - m s^2)``), by Carlson's change of R_J's last argument (DLMF 19.21.12, with his x
    the 1 of DLMF 19.25.14): ``Pi = s R_C(c^2 d^2, p q) - m s^3 / (3 n) R_J(c^2, d^2, 1, q)``,
    ``p = 1 - n s^2``, ``q = 1 - m s^2 / n``, and ``s R_C = atan2(|s| g, c d) / g`` with
    ``g^2 = (1 - n)(1 - m / n)``. Both terms have the sign of ``s``: nothing cancels, where
    DLMF 19.25.14 takes the difference of ``F`` and a third-kind term as large when ``-n`` is
    (a top that passes its pole at 1e-13 has ``n = -4e12``, and lost 6 digits so)."""
    g = math.sqrt((1.0 - n) * (1.0 - m / n))
    circular = math.copysign(math.atan2(abs(s) * g, c * d) / g, s)
    return circular - m * s * s * s / (3.0 * n) * carlson_rj(c * c, d * d, 1.0, 1.0 - m * s * s / n)


@jit
def complete_third_steep(n, m, m1):
    """``Pi(n | m)`` for ``n < 0`` without the cancellation of `complete_third` as ``n -> -inf``
    (`_steep_reduced` at ``phi = pi/2``).

    Parameters
    ----------
    n : float
        The characteristic, < 0.
    m, m1 : float
        The parameter and its complement ``1 - m``, computed without cancellation.

    Returns
    -------
    float
    """
    return _steep_reduced(n, m, 1.0, 0.0, math.sqrt(m1))


@jit
def third_kind_steep(n, sn, cn, dn, u, m, complete):
    """`third_kind` for ``n < 0``, free of its cancellation as ``n -> -inf``
    (`_steep_reduced`).

    Parameters
    ----------
    n : float
        The characteristic, < 0.
    sn, cn, dn : float
        Jacobi's functions of ``u`` (`jacobi`).
    u : float
        The argument, ``|u| <= 2K``.
    m : float
        The parameter.
    complete : float
        ``Pi(n | m)`` (`complete_third_steep`); unused where ``cn >= 0``.

    Returns
    -------
    float
    """
    reduced = _steep_reduced(n, m, sn, abs(cn), dn)
    return _reflected(reduced, cn, u, complete)


@jit
def complete_third_close(n, n1, m1, quarter):
    """`complete_third` given ``n1 = 1 - n`` computed without cancellation (``n`` next to 1).

    Parameters
    ----------
    n : float
        The characteristic, < 1.
    n1 : float
        ``1 - n``, > 0.
    m1 : float
        The complementary parameter ``1 - m``, > 0.
    quarter : float
        ``K(m)`` (`complete_first`).

    Returns
    -------
    float
    """
    return quarter + n / 3.0 * carlson_rj(0.0, m1, 1.0, n1)


@jit
def third_kind_close(n, n1, sn, cn, dn, u, complete):
    """`third_kind` given ``n1 = 1 - n`` computed without cancellation: as ``n -> 1`` the
    last argument ``1 - n sn^2 = n1 + n cn^2`` of R_J is small, and formed as ``1 - n sn^2``
    it kept none of its digits.

    Parameters
    ----------
    n : float
        The characteristic, < 1.
    n1 : float
        ``1 - n``, > 0.
    sn, cn, dn : float
        Jacobi's functions of ``u`` (`jacobi`).
    u : float
        The argument, ``|u| <= 2K``.
    complete : float
        ``Pi(n | m)`` (`complete_third_close`); unused where ``cn >= 0``.

    Returns
    -------
    float
    """
    s2 = sn * sn
    reduced = sn * carlson_rf(cn * cn, dn * dn, 1.0) + n / 3.0 * sn * s2 * carlson_rj(
        cn * cn, dn * dn, 1.0, n1 + n * cn * cn
    )
    return _reflected(reduced, cn, u, complete)


@jit
def _amplitude(u, m, m1):
    """``am(u | m)`` by the arithmetic-geometric mean of ``(1, sqrt(m1))`` and the descending
    Landen transformation (Abramowitz and Stegun 16.4.3); accurate for ``|u| <= K/2``."""
    ratios = np.empty(AGM_MAX_STEPS)
    a, b, c = 1.0, math.sqrt(m1), math.sqrt(m)
    steps = 0
    while c > AGM_TOLERANCE * a and steps < AGM_MAX_STEPS:
        a_next = 0.5 * (a + b)
        # c_{n+1} = (a_n - b_n)/2, written without the subtraction that would cancel
        c = 0.25 * c * c / a_next
        b = math.sqrt(a * b)
        a = a_next
        ratios[steps] = c / a
        steps += 1
    phi = u * a * 2.0**steps
    for i in range(steps - 1, -1, -1):
        phi = 0.5 * (phi + math.asin(ratios[i] * math.sin(phi)))
    return phi


@jit
def _jacobi_near_zero(v, m, m1):
    """``(sn, cn, dn)`` of ``0 <= v <= K/2`` from the amplitude."""
    phi = _amplitude(v, m, m1)
    s, c = math.sin(phi), math.cos(phi)
    d = math.sqrt(c * c + m1 * s * s)
    # One Newton step on F(phi) = v (dF/dphi = 1/dn): the back substitution takes arcsines of
    # arguments near 1 when m is, and left 30 ulps in phi at m1 = 1e-12 (measured against
    # mpmath); F is evaluated to a few ulps, so the step leaves phi good to its last bit.
    phi -= d * (first_kind(s, c, d) - v)
    s, c = math.sin(phi), math.cos(phi)
    return s, c, math.sqrt(c * c + m1 * s * s)


@jit
def jacobi(u, m, m1, quarter):
    """Jacobi's ``(sn, cn, dn)`` of ``u``, relatively accurate in each where it is small.

    On the separatrix (``m1 = 0``) they are ``tanh, sech, sech``. Otherwise ``|u|`` is
    brought to ``[0, K]`` by ``sn(2K - v) = sn v``, ``cn(2K - v) = -cn v`` and the parities;
    beyond ``K/2`` the quarter-period shift (module docstring) takes over.

    Parameters
    ----------
    u : float
        ``|u| <= 2K``.
    m, m1 : float
        The parameter and its complement ``1 - m``, computed without cancellation.
    quarter : float
        ``K(m)``; inf when ``m1 = 0``.

    Returns
    -------
    sn, cn, dn : float
    """
    if m1 == 0.0:
        return math.tanh(u), 1.0 / math.cosh(u), 1.0 / math.cosh(u)
    v = abs(u)
    flip = v > quarter
    if flip:
        v = 2.0 * quarter - v
    if v <= 0.5 * quarter:
        s, c, d = _jacobi_near_zero(v, m, m1)
    else:
        s1, c1, d1 = _jacobi_near_zero(quarter - v, m, m1)
        k1 = math.sqrt(m1)
        s, c, d = c1 / d1, k1 * s1 / d1, k1 / d1
    if flip:
        c = -c
    return math.copysign(s, u), c, d
