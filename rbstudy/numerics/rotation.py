"""Scalar kernels for 3-vectors, 3x3 solves and unit quaternions, on tuples of floats.

Everything here works on tuples so that numba keeps the values in registers: no array is
allocated on the hot path of a step. Quaternions are scalar-last ``(x, y, z, w)`` as in
`scipy.spatial.transform.Rotation`; ``q`` maps body to space, and the body-frame kinematics is
``dq/dt = 1/2 q * (omega, 0)`` (docs/theory.md, section 1).
"""

import math

from rbstudy.numerics import algebra
from rbstudy.numerics.jit import jit

__all__ = [
    "read3",
    "write3",
    "read4",
    "write4",
    "add",
    "sub",
    "scale",
    "axpy",
    "axpy4",
    "dot",
    "dot4",
    "cross",
    "norm",
    "skew_matmul",
    "solve3",
    "quat_mul",
    "quat_conj",
    "quat_normalize",
    "quat_rotate",
    "quat_rotate_inverse",
    "quat_exp",
    "spun_steadily",
    "quat_exp_of",
    "quat_exp_minus_one",
    "quat_cayley",
    "quat_cayley_minus_one",
    "cos_minus_one",
    "quat_mul_axis_rotation",
    "quat_times_axis",
]

# Below this rotation angle (rad) the exponential map uses its Taylor series: the series
# error is below angle^4/3840 ~ 1e-22 there, while sin(x)/x would lose digits.
SMALL_ANGLE = 1e-4


@jit
def read3(a, i):
    """Three consecutive entries ``a[i:i+3]`` of a 1-D array as a tuple.

    Parameters
    ----------
    a : ndarray, shape (n,)
    i : int

    Returns
    -------
    tuple of 3 floats
    """
    return (a[i], a[i + 1], a[i + 2])


@jit
def write3(a, i, v):
    """Store a 3-tuple into ``a[i:i+3]`` (mutates ``a``).

    Parameters
    ----------
    a : ndarray, shape (n,)
    i : int
    v : tuple of 3 floats
    """
    a[i] = v[0]
    a[i + 1] = v[1]
    a[i + 2] = v[2]


@jit
def read4(a, i):
    """Four consecutive entries ``a[i:i+4]`` of a 1-D array as a tuple.

    Parameters
    ----------
    a : ndarray, shape (n,)
    i : int

    Returns
    -------
    tuple of 4 floats
    """
    return (a[i], a[i + 1], a[i + 2], a[i + 3])


@jit
def write4(a, i, v):
    """Store a 4-tuple into ``a[i:i+4]`` (mutates ``a``).

    Parameters
    ----------
    a : ndarray, shape (n,)
    i : int
    v : tuple of 4 floats
    """
    a[i] = v[0]
    a[i + 1] = v[1]
    a[i + 2] = v[2]
    a[i + 3] = v[3]


@jit
def add(a, b):
    """``a + b`` for 3-vectors.

    Parameters
    ----------
    a, b : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@jit
def sub(a, b):
    """``a - b`` for 3-vectors.

    Parameters
    ----------
    a, b : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@jit
def scale(s, a):
    """``s * a`` for a 3-vector.

    Parameters
    ----------
    s : float
    a : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    return (s * a[0], s * a[1], s * a[2])


@jit
def axpy(s, a, b):
    """``s * a + b`` for 3-vectors.

    Parameters
    ----------
    s : float
    a, b : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    return (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2])


@jit
def axpy4(s, a, b):
    """``s * a + b`` for 4-vectors (quaternions).

    Parameters
    ----------
    s : float
    a, b : tuple of 4 floats

    Returns
    -------
    tuple of 4 floats
    """
    return (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2], s * a[3] + b[3])


@jit
def dot4(a, b):
    """``a . b`` for 4-vectors (quaternions).

    Parameters
    ----------
    a, b : tuple of 4 floats

    Returns
    -------
    float
    """
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]


@jit
def dot(a, b):
    """``a . b`` for 3-vectors.

    Parameters
    ----------
    a, b : tuple of 3 floats

    Returns
    -------
    float
    """
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@jit
def cross(a, b):
    """``a x b`` for 3-vectors.

    Parameters
    ----------
    a, b : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@jit
def norm(a):
    """Euclidean length ``|a|`` of a 3-vector.

    Parameters
    ----------
    a : tuple of 3 floats

    Returns
    -------
    float
    """
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@jit
def skew_matmul(a, d):
    """The 3x3 matrix ``[a]x diag(d)`` (used in Newton Jacobians).

    Parameters
    ----------
    a, d : tuple of 3 floats

    Returns
    -------
    tuple of 3 tuples of 3 floats
        Its rows.
    """
    return (
        (0.0, -a[2] * d[1], a[1] * d[2]),
        (a[2] * d[0], 0.0, -a[0] * d[2]),
        (-a[1] * d[0], a[0] * d[1], 0.0),
    )


@jit
def solve3(m, r):
    """Solve ``m x = r`` by Cramer's rule.

    Cramer's rule is exact enough here: the Newton matrices of the implicit schemes are
    ``c * 1 + O(h |omega|)`` and far from singular in the range where Newton converges; a
    singular matrix yields inf/nan, which the caller turns into a status code.

    Parameters
    ----------
    m : tuple of 3 tuples of 3 floats
        The matrix's rows.
    r : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
        ``x``.
    """
    (a, b, c), (d, e, f), (g, h, i) = m
    c0 = e * i - f * h
    c1 = f * g - d * i
    c2 = d * h - e * g
    det = a * c0 + b * c1 + c * c2
    inv = 1.0 / det
    x0 = (r[0] * c0 + b * (f * r[2] - r[1] * i) + c * (r[1] * h - e * r[2])) * inv
    x1 = (a * (r[1] * i - f * r[2]) + r[0] * c1 + c * (d * r[2] - r[1] * g)) * inv
    x2 = (a * (e * r[2] - r[1] * h) + b * (r[1] * g - d * r[2]) + r[0] * c2) * inv
    return (x0, x1, x2)


# Hamilton product ``a * b`` of scalar-last quaternions (the formula numpy code shares).
quat_mul = jit(algebra.hamilton_product)


@jit
def quat_conj(q):
    """The conjugate of a quaternion (the inverse rotation of a unit one).

    Parameters
    ----------
    q : tuple of 4 floats
        Scalar last.

    Returns
    -------
    tuple of 4 floats
    """
    return (-q[0], -q[1], -q[2], q[3])


@jit
def quat_normalize(q):
    """A quaternion scaled to unit length.

    Parameters
    ----------
    q : tuple of 4 floats
        Scalar last, nonzero.

    Returns
    -------
    tuple of 4 floats
    """
    s = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] * s, q[1] * s, q[2] * s, q[3] * s)


@jit
def quat_rotate(q, v):
    """``R(q) v``: a body-frame vector expressed in space.

    Parameters
    ----------
    q : tuple of 4 floats
        Unit quaternion, scalar last, body to space.
    v : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    x, y, z, w = q
    u = (x, y, z)
    t = scale(2.0, cross(u, v))
    return add(add(v, scale(w, t)), cross(u, t))


@jit
def quat_rotate_inverse(q, v):
    """``R(q)^T v``: a space vector expressed in the body frame.

    Parameters
    ----------
    q : tuple of 4 floats
        Unit quaternion, scalar last, body to space.
    v : tuple of 3 floats

    Returns
    -------
    tuple of 3 floats
    """
    return quat_rotate(quat_conj(q), v)


@jit
def quat_exp(v):
    """Unit quaternion of a rotation vector (angle ``|v|`` about ``v/|v|``): ``exp([v]x)``.

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
    if angle < SMALL_ANGLE:  # the series: no sine to take (quat_exp_of does not read it)
        return quat_exp_of(v, angle, 0.0, 1.0)
    half = 0.5 * angle
    return quat_exp_of(v, angle, math.sin(half), math.cos(half))


@jit
def spun_steadily(q, omega, t):
    """``q exp(omega t)``: a body turning at the constant body angular velocity ``omega`` for
    a time ``t`` from ``q`` (a permanent rotation; the sleeping top).

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last.
    omega : tuple of 3 floats
        Body angular velocity (rad/s).
    t : float
        s.

    Returns
    -------
    tuple of 4 floats
    """
    return quat_mul(q, quat_exp((omega[0] * t, omega[1] * t, omega[2] * t)))


@jit
def quat_exp_of(v, angle, sine, cosine):
    """`quat_exp` of the rotation vector ``v`` from its angle ``|v|`` and the sine and cosine
    of half of it (libm's for `quat_exp`, `rbstudy.numerics.lanes_math`'s for the schemes that
    step blocks of bodies): the Taylor series below `SMALL_ANGLE`, chosen by a select, so that
    a loop over bodies that calls it still vectorises.

    Parameters
    ----------
    v : tuple of 3 floats
        Rotation vector (rad).
    angle : float
        ``|v|``.
    sine, cosine : float
        ``sin(angle / 2)``, ``cos(angle / 2)``.

    Returns
    -------
    tuple of 4 floats
        Scalar last.
    """
    small = angle < SMALL_ANGLE
    # sin(half)/angle = 1/2 - angle^2/48 + ...; cos(half) = 1 - angle^2/8 + angle^4/384
    s = 0.5 - angle * angle / 48.0 if small else sine / angle
    c = 1.0 - angle * angle / 8.0 + angle**4 / 384.0 if small else cosine
    return (s * v[0], s * v[1], s * v[2], c)


@jit
def cos_minus_one(s, c):
    """``cos(x) - 1`` from ``s = sin(x)`` and ``c = cos(x)``, without the cancellation of
    ``c - 1`` at small ``x``: ``-s^2 / (1 + c)`` while ``c > 0``.

    Parameters
    ----------
    s, c : float
        The sine and cosine of one angle.

    Returns
    -------
    float
    """
    if c > 0.0:
        return -s * s / (1.0 + c)
    return c - 1.0


@jit
def quat_exp_minus_one(v):
    """``exp([v]x) - 1`` as a quaternion (`quat_exp` less the identity), every component to
    its own relative accuracy: the increment ``q exp([v]x) - q = q * quat_exp_minus_one(v)``
    of a compensated rotation (`rbstudy.numerics.compensated`).

    Parameters
    ----------
    v : tuple of 3 floats
        Rotation vector (rad).

    Returns
    -------
    tuple of 4 floats
        Scalar last: ``(sin(a/2) v / a, cos(a/2) - 1)``, ``a = |v|``.
    """
    angle = norm(v)
    if angle < SMALL_ANGLE:
        s = 0.5 - angle * angle / 48.0
        c = -angle * angle / 8.0 + angle**4 / 384.0
    else:
        half = 0.5 * angle
        s = math.sin(half) / angle
        c = cos_minus_one(math.sin(half), math.cos(half))
    return (s * v[0], s * v[1], s * v[2], c)


@jit
def quat_cayley_minus_one(v):
    """``cay([v]x) - 1`` as a quaternion (`quat_cayley` less the identity), without
    cancellation: the scalar part ``1 / r - 1 = -a / (r (1 + r))``, ``r = sqrt(1 + a)``,
    ``a = |v|^2 / 4``.

    Parameters
    ----------
    v : tuple of 3 floats

    Returns
    -------
    tuple of 4 floats
        Scalar last.
    """
    a = 0.25 * dot(v, v)
    r = math.sqrt(1.0 + a)
    s = 0.5 / r
    return (s * v[0], s * v[1], s * v[2], -a / (r * (1.0 + r)))


@jit
def quat_cayley(v):
    """Unit quaternion of the Cayley map ``cay([v]x) = (1 - [v]x/2)^-1 (1 + [v]x/2)``.

    cay([v]x) is the rotation by ``2 atan(|v|/2)`` about ``v``, whose quaternion is
    proportional to ``(v/2, 1)``.

    Parameters
    ----------
    v : tuple of 3 floats

    Returns
    -------
    tuple of 4 floats
        Scalar last.
    """
    return quat_normalize((0.5 * v[0], 0.5 * v[1], 0.5 * v[2], 1.0))


@jit
def quat_mul_axis_rotation(q, k, s, c):
    """``q * (s e_k, c)``: compose ``q`` with a rotation about coordinate axis ``k``.

    Written out because the right factor has two non-zero entries: a quarter of a full
    `quat_mul`.

    Parameters
    ----------
    q : tuple of 4 floats
        Scalar last.
    k : int
        The axis, 0, 1 or 2.
    s, c : float
        The sine and cosine of half the rotation angle.

    Returns
    -------
    tuple of 4 floats
    """
    x, y, z, w = q
    if k == 0:
        return (x * c + w * s, y * c + z * s, z * c - y * s, w * c - x * s)
    if k == 1:
        return (x * c - z * s, y * c + w * s, z * c + x * s, w * c - y * s)
    return (x * c + y * s, y * c - x * s, z * c + w * s, w * c - z * s)


@jit
def quat_times_axis(q, k):
    """``q * (e_k, 0)``: right multiplication by a pure unit quaternion along axis ``k``.

    This is NO_SQUISH's permutation matrix ``P_k`` (Miller et al. 2002) in scalar-last form.

    Parameters
    ----------
    q : tuple of 4 floats
        Scalar last.
    k : int
        The axis, 0, 1 or 2.

    Returns
    -------
    tuple of 4 floats
    """
    x, y, z, w = q
    if k == 0:
        return (w, z, -y, -x)
    if k == 1:
        return (-z, w, x, -y)
    return (y, -x, w, -z)
