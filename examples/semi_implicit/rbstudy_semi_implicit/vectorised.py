"""`semi_implicit_numpy`: the package's step in numpy over a batch of bodies (package
docstring): the kind of scheme that wraps foreign code, slower than a compiled kernel."""

import numpy as np

from rbstudy.extending import OK, Scheme, algebra, batch_loads, make_batch_entry
from rbstudy.extending import state as S


def _quat_exp(v):
    """Unit quaternions (n, 4), scalar last, of the rotation vectors ``v`` (n, 3)."""
    angle = np.linalg.norm(v, axis=1)
    half = 0.5 * angle
    # sin(half) / angle, with its series near 0 (the compiled kernels' switch point)
    small = angle < 1e-4
    ratio = np.where(small, 0.5 - angle * angle / 48.0,
                     np.sin(half) / np.where(small, 1.0, angle))
    cosine = np.where(small, 1.0 - angle * angle / 8.0 + angle ** 4 / 384.0, np.cos(half))
    return np.concatenate([ratio[:, None] * v, cosine[:, None]], axis=1)


def _skew(a):
    """Cross-product matrices (n, 3, 3) of the vectors ``a`` (n, 3)."""
    zero = np.zeros(len(a))
    return np.stack([np.stack([zero, -a[:, 2], a[:, 1]], axis=1),
                     np.stack([a[:, 2], zero, -a[:, 0]], axis=1),
                     np.stack([-a[:, 1], a[:, 0], zero], axis=1)], axis=1)


def step(y, p, opt, t, h, work):
    q = y[:, S.QUATERNION:S.QUATERNION + 4]
    w = y[:, S.OMEGA:S.OMEGA + 3]
    inertia = p[:, S.INERTIA:S.INERTIA + 3]
    m = inertia * w
    force, moment = batch_loads(y, p, t)
    rate = moment - np.cross(w, m)
    # I + h ([w]x I - [m]x): the derivative of h (w x I w) in w, added to I
    jacobian = (np.eye(3) * inertia[:, None, :]
                + h * (_skew(w) * inertia[:, None, :] - _skew(m)))
    w_next = w + np.linalg.solve(jacobian, h * rate[:, :, None])[:, :, 0]
    v_next = y[:, S.VELOCITY:S.VELOCITY + 3] + (h / p[:, S.MASS])[:, None] * force
    # the Hamilton product over component-first arrays, as rbstudy's own numpy code takes it
    q_next = np.stack(algebra.hamilton_product(q.T, _quat_exp(h * w_next).T), axis=1)
    y[:, S.VELOCITY:S.VELOCITY + 3] = v_next
    y[:, S.POSITION:S.POSITION + 3] += h * v_next
    y[:, S.QUATERNION:S.QUATERNION + 4] = q_next / np.linalg.norm(q_next, axis=1)[:, None]
    y[:, S.OMEGA:S.OMEGA + 3] = w_next
    return OK, 0


SCHEME = Scheme(
    name="semi_implicit_numpy",
    summary="example plug-in: semi_implicit as one numpy step over the batch (slower; "
            "the kind that wraps foreign code)",
    step_seconds=2e-06,
    order=1,
    implicit=False,
    kind="linearly implicit",  # one linear solve a step, no Newton iterations
    keeps=(),
    run_bodies_inplace=make_batch_entry(step),
    reference="Catto, Physics for game programmers: numerical methods, GDC 2015",
)
