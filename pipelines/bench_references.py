"""Print the reference figures of docs/performance.md: the cost per case of the exact free-body
reference (`exact_asymmetric`, compiled) against a DOP853 reference at 1e-13 for the same
free asymmetric body, and how far DOP853 is from the exact solution at the end of the run.

Usage: python pipelines/bench_references.py

The body is the plate of configs/long_run_convergence.yaml, over 10 s (201 output times) and
1000 s (1001). The exact reference is timed for one case and per case in a batch of 100
(compilation done first), DOP853 for one case.
"""

import time

import numpy as np

from rbstudy.numerics.driver import HALT_FLAG
from rbstudy.numerics.state import STATE_FIELDS
from rbstudy.physics.metrics import orientation_error
from rbstudy.physics.references import reference_solutions
from rbstudy.physics.scenes import Body, Scene
from rbstudy.schemes import dop853

PLATE = Scene(
    body=Body(mass=1.0, inertia=(0.35, 0.65, 1.0)),
    quaternion=(0.0, 0.0, 0.0, 1.0),
    omega_body=(0.6, 1.5, 0.9),
    duration=1000.0,
)


def _per_case(scenes, times):
    start = time.perf_counter()
    references = reference_solutions(scenes, times)
    return (time.perf_counter() - start) / len(scenes), references[0]


def main():
    for duration, count in ((10.0, 201), (1000.0, 1001)):
        times = np.linspace(0.0, duration, count)
        reference_solutions([PLATE], times)  # compile, or load from the cache
        alone, exact = _per_case([PLATE], times)
        batched, _ = _per_case([PLATE] * 100, times)
        start = time.perf_counter()
        run = dop853.integrate(PLATE.state_row(), PLATE.param_row(), times, max_steps=10**7, halt=HALT_FLAG)
        integrated = time.perf_counter() - start
        drift = orientation_error(run.samples[-1, STATE_FIELDS["quaternion"]], exact.quaternion[-1])
        print(
            f"{duration:6.0f} s, {count} times: exact {alone * 1e3:.2f} ms a case alone, "
            f"{batched * 1e3:.2f} ms in a batch of 100; DOP853 {integrated * 1e3:.0f} ms "
            f"({integrated / alone:.0f}x), {drift:.1e} rad off the exact solution at the end"
        )


if __name__ == "__main__":
    main()
