"""Sine and cosine that LLVM can vectorise across bodies, and the rotation they serve.

A call of libm's ``sin`` inside a loop over bodies stops LLVM from vectorising that loop: the
call is opaque and scalar. numba's vectorised sine (Intel's SVML, where installed) gives other
bits than libm's, so a body would not get the same numbers in a batch as alone. Here the sine
and cosine are polynomials in plain arithmetic, the same code on the one-body path and on the
path over a block of bodies (`rbstudy.numerics.block`), so a body's bits never depend on its
batch.

Method (fdlibm's, as musl writes it; docs/theory.md s4):
- reduction: ``x = n pi/2 + r``, ``n = rint(x 2/pi)``, with pi/2 in three parts of 33 bits each
  (Cody and Waite): ``n`` times a part is exact for ``|n| < 2^20``, and the remainder is kept
  as ``r + r_tail``, so that it is right to ~2^-100 relative to ``|x|``;
- kernels on ``|r| <= pi/4``: odd and even minimax polynomials of degree 13 and 14 with musl's
  coefficients, the tail entering to first order;
- the quadrant ``n mod 4`` chooses sign and kernel with selects, not branches.
Measured against numpy over 4e6 random arguments and the edges (`tests/test_lanes_math.py`):
within 1 ulp (`ULPS`) for ``|x| <= REDUCED``. Beyond that (a step that turns the body by more
than 1.6e6 rad, long past any bound) `sin_cos` calls libm instead, on both paths alike, and
NaN and infinities give NaN.
"""

import math

from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import norm, quat_exp_of

__all__ = ["ULPS", "REDUCED", "sin_cos", "sin_cos_reduced", "quat_exp_poly"]

# The largest error of `sin_cos` against a correctly rounded sine and cosine, in units in the
# last place (measured; tests/test_lanes_math.py holds it).
ULPS = 1
# Arguments up to this size reduce exactly (|n| < 2^20): 2^20 pi/4, so that n <= 2^19.
REDUCED = 2.0**19 * math.pi / 2.0

_TWO_OVER_PI = 6.36619772367581382433e-01
# Below this, x 2/pi < 0.4966 rounds to n = 0 whatever the rounding of the product: no reduction.
_UNREDUCED = 0.78
# Adding and subtracting 1.5 * 2^52 rounds a double of magnitude < 2^51 to an integer (ties to
# even), without a call: a libm ``rint`` would stop the vectorisation.
_ROUNDER = 6755399441055744.0
# pi/2 in three parts of 33 bits (fdlibm's pio2_1, pio2_2, pio2_3), each with the tail of
# its part (pio2_2t, pio2_3t).
_PIO2_1 = 1.57079632673412561417e00
_PIO2_2 = 6.07710050630396597660e-11
_PIO2_2T = 2.02226624879595063154e-21
_PIO2_3 = 2.02226624871116645580e-21
_PIO2_3T = 8.47842766036889956997e-32
# musl's kernels (__sin.c, __cos.c): |error| < 2^-58 of the result on |r| <= pi/4.
_S1 = -1.66666666666666324348e-01
_S2 = 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4 = 2.75573137070700676789e-06
_S5 = -2.50507602534068634195e-08
_S6 = 1.58969099521155010221e-10
_C1 = 4.16666666666666019037e-02
_C2 = -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4 = -2.75573143513906633035e-07
_C5 = 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11


@jit
def _kernels(r, tail):
    """musl's ``__sin(r, tail, 1)`` and ``__cos(r, tail)`` of ``r + tail``, ``|r| <= pi/4``."""
    z = r * r
    zz = z * z
    v = z * r
    ps = _S2 + z * (_S3 + z * _S4) + z * zz * (_S5 + z * _S6)
    sine = r - ((z * (0.5 * tail - v * ps) - tail) - v * _S1)
    pc = z * (_C1 + z * (_C2 + z * _C3)) + zz * zz * (_C4 + z * (_C5 + z * _C6))
    hz = 0.5 * z
    one_less = 1.0 - hz
    cosine = one_less + (((1.0 - one_less) - hz) + (z * pc - r * tail))
    return sine, cosine


@jit
def sin_cos_reduced(x):
    """``(sin x, cos x)`` for ``|x| <= REDUCED`` (anything finite beyond it), in plain
    arithmetic and selects: the branch-free body of a loop that LLVM vectorises.

    Parameters
    ----------
    x : float
        Radians.

    Returns
    -------
    tuple of 2 floats
    """
    n = (x * _TWO_OVER_PI + _ROUNDER) - _ROUNDER
    # remainder in three rounds (fdlibm's __rem_pio2 for medium arguments, every round
    # taken: no branch), kept as r + tail
    r = x - n * _PIO2_1
    head = r
    w = n * _PIO2_2
    r = head - w
    w = n * _PIO2_2T - ((head - r) - w)
    head = r
    w = n * _PIO2_3
    r = head - w
    w = n * _PIO2_3T - ((head - r) - w)
    head = r
    r = head - w
    tail = (head - r) - w
    sine, cosine = _kernels(r, tail)
    quadrant = int(n) & 3
    s = cosine if quadrant & 1 else sine
    c = sine if quadrant & 1 else cosine
    s = -s if quadrant & 2 else s
    c = -c if (quadrant + 1) & 2 else c
    return s, c


@jit
def sin_cos(x):
    """``(sin x, cos x)`` to within `ULPS`: `sin_cos_reduced` where it reduces exactly, libm
    beyond (and for NaN and infinities, which give NaN).

    Parameters
    ----------
    x : float
        Radians.

    Returns
    -------
    tuple of 2 floats
    """
    if abs(x) < _UNREDUCED:
        # the bits of sin_cos_reduced, whose reduction gives n = 0, r = x, tail = 0 here, at
        # a third of its cost on one body (a step's half angle is nearly always this small)
        return _kernels(x, 0.0)
    if abs(x) <= REDUCED:
        return sin_cos_reduced(x)
    return math.sin(x), math.cos(x)


@jit
def quat_exp_poly(v):
    """`rbstudy.numerics.rotation.quat_exp` with the sine and cosine of `sin_cos`: the rotation
    of the schemes that step blocks of bodies (`rbstudy.numerics.block`), one body at a time.

    Parameters
    ----------
    v : tuple of 3 floats
        Rotation vector (rad).

    Returns
    -------
    tuple of 4 floats
        Scalar last.
    """
    angle = norm(v)
    sine, cosine = sin_cos(0.5 * angle)
    return quat_exp_of(v, angle, sine, cosine)
