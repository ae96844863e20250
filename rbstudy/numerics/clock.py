"""The time a kernel is at, or no time at all: two compiled variants of every kernel.

Loads tabulated in time need the time of every evaluation; constant loads do not. A branch
"are there tabulated loads?" inside the moment and the force that every stage evaluates cost
the free body a fifth to a third of its steps per second even though it was never taken
(`pipelines/bench_loads.py` measures it). So the decision is
made by type, once per batch: the driver passes the time ``t`` as a float when some body of
the batch has tabulated loads, and as None otherwise (`rbstudy.numerics.driver.run_batch`).
numba compiles each kernel once per type of ``t``; under None the functions below resolve,
while typing, to code without the time, and the tabulated loads vanish from the kernels.
A kind of load that is rare and costs a check where it is absent rides along: the catalogue
marks it (`rbstudy.numerics.loads.LoadKind.timed_kernels`), the batches that carry it get the
time too (`rbstudy.numerics.loads.needs_time`), and the kernels reach it through
`without_time` as well.

Kernels therefore write a stage's time as ``later(t, d)``, never ``t + d``, and reach a
function of the time through `without_time`.
"""

from collections.abc import Callable
from typing import Any

from numba import types
from numba.extending import overload

__all__ = ["later", "step_time", "without_time"]


def later(t: float | None, d: float) -> float | None:
    """The time ``d`` after ``t``, or no time.

    Parameters
    ----------
    t : float or None
        A time (s); None in a batch without loads tabulated in time.
    d : float
        s.

    Returns
    -------
    float or None
        ``t + d``; None when ``t`` is None.
    """
    return None if t is None else t + d


def step_time(steps: int, h: float, clock: float | None) -> float | None:
    """The time after ``steps`` steps of ``h``: a product, so that no running sum drifts over
    1e9 steps.

    Parameters
    ----------
    steps : int
    h : float
        The step (s).
    clock : float or None
        A number where the kernels take the time, None where they do not.

    Returns
    -------
    float or None
        ``steps * h``; None when ``clock`` is None.
    """
    return None if clock is None else steps * h


@overload(later, inline="always")
def _later(t, d):
    if isinstance(t, types.NoneType):
        return lambda t, d: None
    return lambda t, d: t + d


@overload(step_time, inline="always")
def _step_time(steps, h, clock):
    if isinstance(clock, types.NoneType):
        return lambda steps, h, clock: None
    return lambda steps, h, clock: steps * h


def without_time(of_time: Callable[..., Any]) -> Callable[..., Any]:
    """A compiled function ``of_time(x, p, t)`` that gives a 3-vector (of the time, or of a
    load only the kernels with the time carry), as one that compiled code may also call with
    ``t`` None, and that gives zero then.

    Parameters
    ----------
    of_time : compiled function ``(x, p, t) -> tuple of 3 floats``
        ``x`` a state part (a quaternion 4-tuple or a spin 3-tuple), ``p`` a parameter row
        (W,), ``t`` a time (s).

    Returns
    -------
    function ``(x, p, t) -> tuple of 3 floats``
        ``of_time(x, p, t)``, or ``(0.0, 0.0, 0.0)`` where ``t`` is None (compiled away).
    """

    def timed(q, p, t):
        return (0.0, 0.0, 0.0) if t is None else of_time(q, p, t)

    @overload(timed, inline="always")
    def _timed(q, p, t):
        if isinstance(t, types.NoneType):
            return lambda q, p, t: (0.0, 0.0, 0.0)
        return lambda q, p, t: of_time(q, p, t)

    timed.__name__ = timed.__qualname__ = f"timed_{of_time.__name__}"
    return timed
