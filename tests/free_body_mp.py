"""An independent, high-precision evaluation of the free rigid body's exact solution, for the
tests of `rbstudy.numerics.free_flow`: the same formulas (docs/theory.md s3) written directly
in mpmath at 40 digits, with mpmath's own Jacobi functions and Legendre integrals (neither
Carlson's duplication nor the Landen transformation of `rbstudy.numerics.elliptic`), no
reduction tricks, every quantity from the float inputs taken as exact. Slow (~10 ms a
time); it serves as the oracle of what float64 could give at best.
"""

import mpmath as mp

DIGITS = 40


def _qmul(a, b):
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _tilt(m1, m2, m3):
    """Quaternion of Rot(e1, theta) Rot(e3, psi), cos theta = m3/G, psi = atan2(m1, m2)."""
    theta = mp.atan2(mp.sqrt(m1**2 + m2**2), m3)
    psi = mp.atan2(m1, m2)
    tilt = (mp.sin(theta / 2), 0, 0, mp.cos(theta / 2))
    return _qmul(tilt, (0, 0, mp.sin(psi / 2), mp.cos(psi / 2)))


def exact_state(inertia, q0, omega0, t):
    """(quaternion, omega) at ``t`` as mpf tuples, for a body that is neither symmetric nor in
    a permanent rotation (k^2 < 1)."""
    with mp.workdps(DIGITS):
        inertia = [mp.mpf(float(v)) for v in inertia]
        w = [mp.mpf(float(v)) for v in omega0]
        q0 = [mp.mpf(float(v)) for v in q0]
        t = mp.mpf(float(t))
        m = [i * x for i, x in zip(inertia, w, strict=True)]
        g2 = sum(x * x for x in m)
        e2 = sum(x * y for x, y in zip(m, w, strict=True))
        order = sorted(range(3), key=lambda j: inertia[j])
        lo, mid, hi = order
        first, third = (lo, hi) if g2 - e2 * inertia[mid] > 0 else (hi, lo)
        s1 = 1 if mid == (first + 1) % 3 else -1
        i1, i2, i3 = inertia[first], inertia[mid], inertia[third]
        w1, w2, w3 = s1 * w[first], w[mid], w[third]
        a1 = mp.sign(w1) * mp.sqrt((e2 * i3 - g2) / (i1 * (i3 - i1)))
        a2 = mp.sqrt((e2 * i3 - g2) / (i2 * (i3 - i2)))
        a3 = mp.sign(w3) * mp.sqrt((g2 - e2 * i1) / (i3 * (i3 - i1)))
        lam = (i3 - i2) * a2 * a3 / (i1 * a1)
        k2 = (i2 - i1) * (e2 * i3 - g2) / ((i3 - i2) * (g2 - e2 * i1))
        n = -i3 * (i2 - i1) / (i1 * (i3 - i2))
        phi0 = mp.atan2(w2 / a2, w1 / a1)
        u0 = mp.ellipf(phi0, k2)
        u = u0 + lam * t
        sn, cn, dn = (mp.ellipfun(name, u, m=k2) for name in ("sn", "cn", "dn"))
        quarter = mp.ellipk(k2)
        half_turns = mp.floor((u + quarter) / (2 * quarter))  # am(u) within pi/2 of j pi
        amplitude = _unwrap(mp.atan2(sn, cn), half_turns)
        g = mp.sqrt(g2)
        precession = g * t / i3 + g * (i3 - i1) / (i1 * i3 * lam) * (
            _third(n, amplitude, k2) - _third(n, phi0, k2)
        )
        b0 = _tilt(i1 * w1, i2 * w2, i3 * w3)
        b_t = _tilt(i1 * a1 * cn, i2 * a2 * sn, i3 * a3 * dn)
        relative = _qmul(
            _qmul((-b0[0], -b0[1], -b0[2], b0[3]), (0, 0, mp.sin(precession / 2), mp.cos(precession / 2))),
            b_t,
        )
        vector, velocity = [0, 0, 0], [0, 0, 0]
        for axis, sign, v, x in (
            (first, s1, relative[0], a1 * cn),
            (mid, 1, relative[1], a2 * sn),
            (third, 1, relative[2], a3 * dn),
        ):
            vector[axis], velocity[axis] = sign * v, sign * x
        return _qmul(tuple(q0), (*vector, relative[3])), tuple(velocity)


def _unwrap(angle, half_turns):
    """The angle equal to ``angle`` modulo 2 pi within pi/2 of ``half_turns`` pi."""
    return angle + 2 * mp.pi * mp.nint((half_turns * mp.pi - angle) / (2 * mp.pi))


def _third(n, amplitude, k2):
    """Legendre's Pi(n; amplitude | k2) for any real amplitude."""
    turns = mp.nint(amplitude / mp.pi)
    return 2 * turns * mp.ellippi(n, k2) + mp.ellippi(n, amplitude - turns * mp.pi, k2)


def angle_between(q_mp, q):
    """Geodesic angle (rad, float) between an mpf quaternion and a float one."""
    with mp.workdps(DIGITS):
        rel = _qmul((-q_mp[0], -q_mp[1], -q_mp[2], q_mp[3]), tuple(mp.mpf(float(v)) for v in q))
        return float(2 * mp.atan2(mp.sqrt(rel[0] ** 2 + rel[1] ** 2 + rel[2] ** 2), abs(rel[3])))
