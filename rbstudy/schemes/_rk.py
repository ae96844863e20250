"""The classical fourth-order Runge-Kutta tableau, shared by `rk4` and `rkmk4`: where each
stage takes its rates, with what weight they join the sum ``k1 + 2 k2 + 2 k3 + k4``, and the
step's end from that sum. Both schemes' single-body and block steps read it from here."""

from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import axpy, axpy4

# stage i's point is ``y + (NODES[i] h) k``, k the rates of stage i - 1 (the first's is y),
# its time ``t + NODES[i] h``; its rates join the sum with WEIGHTS[i]
_NODES = (0.0, 0.5, 0.5, 1.0)
_WEIGHTS = (1.0, 2.0, 2.0, 1.0)


# inlined by numba: called with ``i`` a literal, a kernel of its own would be compiled once per stage
@inline_jit
def rk4_stage(h, i):
    """Stage ``i`` (0 .. 3) of a step ``h``: ``(a, weight)``, its point ``y + a k`` from the
    last stage's rates ``k`` (its time ``t + a``), and its rates' weight in the sum."""
    return _NODES[i] * h, _WEIGHTS[i]


@jit
def rk4_end3(h, y, s):
    """``y + h/6 s`` for 3-tuples, ``s`` the weighted sum of the stages' rates, accumulated
    stage by stage with `rbstudy.numerics.rotation.axpy`: ``((k1 + 2 k2) + 2 k3) + k4``."""
    return axpy(h / 6.0, s, y)


@jit
def rk4_end4(h, y, s):
    """`rk4_end3` for 4-tuples (a quaternion)."""
    return axpy4(h / 6.0, s, y)
