"""`semi_implicit`: the package's step as compiled single-body kernels (package docstring)."""

from rbstudy.extending import OK, Scheme, init_nothing, jit, make_entry
from rbstudy.extending import dynamics as D
from rbstudy.extending import rotation as R
from rbstudy.extending import state as S

N_WORK = 0


@jit
def step_inplace(y, p, opt, t, h, work):
    q = R.read4(y, S.QUATERNION)
    w = R.read3(y, S.OMEGA)
    inertia = D.inertia(p)
    m = D.to_momentum(w, inertia)
    rate = R.sub(D.body_moment(q, w, p, t), R.cross(w, m))
    # I + h ([w]x I - [m]x): the derivative of h (w x I w) in w, added to I
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = R.skew_matmul(w, inertia)
    (d0, d1, d2), (e0, e1, e2), (f0, f1, f2) = R.skew_matmul(m, (1.0, 1.0, 1.0))
    jacobian = ((inertia[0] + h * (a0 - d0), h * (a1 - d1), h * (a2 - d2)),
                (h * (b0 - e0), inertia[1] + h * (b1 - e1), h * (b2 - e2)),
                (h * (c0 - f0), h * (c1 - f1), inertia[2] + h * (c2 - f2)))
    w_next = R.add(w, R.solve3(jacobian, R.scale(h, rate)))
    v_next = R.axpy(h / p[S.MASS], D.space_force(q, p, t), R.read3(y, S.VELOCITY))
    R.write3(y, S.VELOCITY, v_next)
    R.write3(y, S.POSITION, R.axpy(h, v_next, R.read3(y, S.POSITION)))
    R.write4(y, S.QUATERNION, R.quat_normalize(R.quat_mul(q, R.quat_exp(R.scale(h, w_next)))))
    R.write3(y, S.OMEGA, w_next)
    return OK, 0


SCHEME = Scheme(
    name="semi_implicit",
    summary="example plug-in: semi-implicit Euler, gyroscopic term linearised-implicit "
            "(as engines step a body)",
    step_seconds=6e-08,
    order=1,
    implicit=False,
    kind="linearly implicit",  # one linear solve a step, no Newton iterations
    keeps=(),
    run_bodies_inplace=make_entry(step_inplace, init_nothing, N_WORK),
    reference="Catto, Physics for game programmers: numerical methods, GDC 2015",
)
