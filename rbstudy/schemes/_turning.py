"""The two paths of an explicit step that turns the frame by a rotation vector (`euler`,
`leapfrog`).

Such a scheme writes its step once, as a kernel over one body's values,

    advance(x, v, w, inertia, moment, mass, force, h) -> (x+, v+, w+, turn)

the loads at the start of the step in (``moment`` N m, body axes; ``force`` N, space axes), the
position, velocity and spin after it and the rotation vector ``turn`` (rad, body axes) out.
`turning_step` runs it on one body's state row and turns the frame at once,
``q <- normalise(q exp(turn))``; `turning_block_step` runs it on every lane of a block
(`rbstudy.numerics.block`) and turns the frames afterwards, in a loop of their own over the
lanes that vectorises (`turn_columns`). Both are inlined into the scheme's kernels with its
``advance`` passed as a value (as `rbstudy.schemes._composition` passes a step), so that each
scheme's kernels are its own and a body gets the same bits on either path.
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.block import BLOCK, PARAM, STATE, column3, column4, loads_at, set_column3, turn_columns
from rbstudy.numerics.dynamics import body_moment, inertia, space_force
from rbstudy.numerics.jit import inline_jit
from rbstudy.numerics.lanes_math import quat_exp_poly
from rbstudy.numerics.rotation import quat_mul, quat_normalize, read3, read4, write3, write4
from rbstudy.numerics.state import OK

__all__ = ["turning_step", "turning_block_step"]


@inline_jit
def turning_step(advance, y, p, t, h):
    """Step one body by ``h`` with ``advance`` (module docstring), under its loads at time
    ``t``: ``y`` (N_STATE,) its state row, ``p`` (N_PARAM,) its parameters. Returns
    ``(OK, 0)``, the status and iterations of a scheme's step."""
    q, w = read4(y, S.QUATERNION), read3(y, S.OMEGA)
    x, v, w, turn = advance(
        read3(y, S.POSITION),
        read3(y, S.VELOCITY),
        w,
        inertia(p),
        body_moment(q, w, p, t),
        p[S.MASS],
        space_force(q, p, t),
        h,
    )
    write3(y, S.POSITION, x)
    write3(y, S.VELOCITY, v)
    write4(y, S.QUATERNION, quat_normalize(quat_mul(q, quat_exp_poly(turn))))
    write3(y, S.OMEGA, w)
    return OK, 0


@inline_jit
def turning_block_step(advance, block, h, turn_rows):
    """`turning_step` of every lane of ``block`` (N_ROWS * BLOCK,), bodies without a lever, a
    body-fixed force or loads in time; ``turn_rows`` the first of the scheme's `TURN_ROWS`
    scratch rows, which hold the rotation vectors and then their quaternions."""
    for lane in range(BLOCK):
        q, w = column4(block, STATE + S.QUATERNION, lane), column3(block, STATE + S.OMEGA, lane)
        moment, mass, force = loads_at(block, q, w, lane)
        x, v, w, turn = advance(
            column3(block, STATE + S.POSITION, lane),
            column3(block, STATE + S.VELOCITY, lane),
            w,
            column3(block, PARAM + S.INERTIA, lane),
            moment,
            mass,
            force,
            h,
        )
        set_column3(block, STATE + S.POSITION, lane, x)
        set_column3(block, STATE + S.VELOCITY, lane, v)
        set_column3(block, STATE + S.OMEGA, lane, w)
        set_column3(block, turn_rows, lane, turn)
    turn_columns(block, turn_rows)
