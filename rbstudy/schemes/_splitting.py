"""The symmetric five-flow composition shared by the splitting schemes (splitting, no_squish).

The kinetic energy splits into the axis parts ``T_k = m_k^2 / (2 I_k)``; a step composes their
exact flows as ``T_a(h/2) T_b(h/2) T_c(h) T_b(h/2) T_a(h/2)`` for the axis order ``abc``
(Dullweber, Leimkuhler & McLachlan 1997; Fasso 2003 on how much the order matters). Each
scheme writes the flow of one ``T_k`` in its own variables and walks `flow_sequence`.
"""

from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.schemes._registry import Option

__all__ = ["AXIS_ORDER", "flow_sequence", "on_axis"]


def _parse_axis_order(value):
    text = str(value)
    if sorted(text) != ["1", "2", "3"]:
        raise ValueError("expected a permutation of the axes 1, 2, 3 such as '123' or '213'")
    return tuple(float(int(c) - 1) for c in text)


AXIS_ORDER = Option(
    name="axis_order",
    default="123",
    description=(
        "order of the free sub-flows 'abc' in T_a(h/2) T_b(h/2) T_c(h) T_b(h/2) T_a(h/2); "
        "it changes the error constant a lot (Fasso 2003)"
    ),
    width=3,
    parse=_parse_axis_order,
    long_name="order of the axes' free sub-flows",  # a label such as "213": no units
)


@jit
def flow_sequence(opt, slot):
    """The step's sub-flows as ``(axis k, fraction of h)`` pairs, for the axis order packed
    from ``slot`` on in the option row ``opt`` (N_OPTION,) by `AXIS_ORDER`."""
    a, b, c = int(opt[slot]), int(opt[slot + 1]), int(opt[slot + 2])
    return ((a, 0.5), (b, 0.5), (c, 1.0), (b, 0.5), (a, 0.5))


@inline_jit
def on_axis(loops, block, k, d):
    """``loops(block, k, d)``, a scheme's flow of ``T_k`` on a block of bodies
    (`rbstudy.numerics.block`), with the axis ``k`` a constant of each of three copies, so that
    the loops over the lanes hold no branch on it (one that did kept splitting's turn scalar:
    1.1e7 -> 2.0e7 lane-steps/s, docs/performance.md)."""
    if k == 0:
        loops(block, 0, d)
    elif k == 1:
        loops(block, 1, d)
    else:
        loops(block, 2, d)
