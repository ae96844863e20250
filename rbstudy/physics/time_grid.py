"""A run's time grid, defined once for every layer: the whole number of steps of ``dt`` in an
output interval (`steps_per`), the samples a run keeps (`output_count`), their times
(`output_times`) and the steps it takes (`step_count`).

numpy only (no numba), so that the archive's writers and readers take the grid from here
without compiling anything.
"""

import numpy as np

from rbstudy.errors import InputError

__all__ = ["steps_per", "output_count", "output_times", "step_count", "STEP_RTOL", "MAX_STEPS_PER_INTERVAL"]

# A time step "divides" an interval when the quotient is within this relative distance of an
# integer: decimal inputs such as 0.01 and 2.0 are not exact binary fractions.
STEP_RTOL = 1e-9
# Beyond this many steps in one interval the divisibility test itself loses its meaning (the
# quotient's rounding passes STEP_RTOL) and no run could finish.
MAX_STEPS_PER_INTERVAL = 1e12


def steps_per(interval: float, step: float, step_name: str = "dt", interval_name: str = "interval") -> int:
    """The whole number of ``step``s in ``interval``; an unplaced `InputError` if there is
    none (the caller knows the file and key)."""
    ratio = interval / step
    if not ratio < MAX_STEPS_PER_INTERVAL:  # inf for a subnormal step, NaN for a NaN
        raise InputError(
            f"{step_name} = {step:g} s is too small for the {interval_name} "
            f"{interval:g} s (over {MAX_STEPS_PER_INTERVAL:.0e} steps)",
            f"choose {step_name} = {interval:g} / n with a reasonable n",
        )
    count = round(ratio)
    if count < 1 or abs(ratio - count) > STEP_RTOL * ratio:
        raise InputError(
            f"{step_name} = {step:g} s does not divide the {interval_name} {interval:g} s "
            f"({interval:g} / {step:g} = {ratio:.6g})",
            f"choose {step_name} = {interval:g} / n",
        )
    return int(count)


def output_count(duration: float, output_interval: float) -> int:
    """How many samples a run of ``duration`` (s) keeps: one at t = 0 and one per output
    interval, which must divide the duration (an unplaced `InputError` if not)."""
    return steps_per(duration, output_interval, "output interval", "duration") + 1


def output_times(n_times: int, output_interval: float) -> np.ndarray:
    """The sample times (T,) s, ``k * output_interval`` for k < ``n_times``: where the schemes
    are sampled and the references evaluated. (The archive labels them by the nearest decimal,
    `rbstudy.archive.layout.decimal_grid`.)"""
    return np.arange(n_times) * output_interval


def step_count(duration: float, output_interval: float, dt: float) -> int:
    """How many steps of ``dt`` a run of ``duration`` takes: a whole number per output
    interval, which divides the duration (an unplaced `InputError` if not)."""
    every = steps_per(output_interval, dt, "dt", "output interval")
    return (output_count(duration, output_interval) - 1) * every
