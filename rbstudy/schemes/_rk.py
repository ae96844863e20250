"""The classical fourth-order Runge-Kutta weights, shared by `rk4` and `rkmk4`."""

from rbstudy.numerics.jit import jit


@jit
def rk4_sum3(h, y, k1, k2, k3, k4):
    """``y + h/6 (k1 + 2 k2 + 2 k3 + k4)`` for 3-tuples."""
    c = h / 6.0
    return (
        y[0] + c * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
        y[1] + c * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
        y[2] + c * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]),
    )


@jit
def rk4_sum4(h, y, k1, k2, k3, k4):
    """``y + h/6 (k1 + 2 k2 + 2 k3 + k4)`` for 4-tuples."""
    head = rk4_sum3(h, y, k1, k2, k3, k4)
    c = h / 6.0
    return (head[0], head[1], head[2], y[3] + c * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]))
