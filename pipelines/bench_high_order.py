"""Print the work-precision figures of docs/performance.md: the cost per case at which each
scheme reaches a final orientation error of 1e-8 and 1e-10 rad after 100 s on an asymmetric
body under a space-fixed moment, side by side with DOP853; and the free body, which
`exact_split` integrates in a single step.

Usage: python pipelines/bench_high_order.py

The body is I = (1, 2, 3), w0 = (0.6, 1.5, 0.9) rad/s, from the rotation vector
(0.3, -0.2, 0.5), under M = (0, 0.15, 0) N m in space axes. The reference is exact_split
composed to order 8 at dt = 0.005 s; its own error is estimated by the same at dt = 0.01 s
(order 8: that difference bounds it by far) and it is cross-checked against DOP853 at
rtol = atol = 1e-13. Each scheme runs over halved steps; the cost at a target is interpolated
log-log between the two runs that bracket it, from the kernel CPU time of a batch of 64
copies of the case (compilation done first), per case.
"""

import time

import numpy as np

from rbstudy.numerics.driver import HALT_FLAG
from rbstudy.numerics.state import STATE_FIELDS
from rbstudy.physics.metrics import orientation_error
from rbstudy.physics.references import reference_solutions
from rbstudy.physics.scenes import scene_from_mapping
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import dop853

# rad, final orientation errors. 1e-12 is out of reach of the measurement: the reference's own
# error over 100 s is ~2.5e-11 (round-off of its 20,000 steps of 17 stages), and so is that of
# every stepping scheme at such step counts (docs/performance.md)
TARGETS = (1e-8, 1e-10)
BATCH = 64
BODY = {"body": {"inertia": [1.0, 2.0, 3.0]},
        "initial": {"angular_velocity": {"body": [0.6, 1.5, 0.9]},
                    "orientation": {"rotation_vector": [0.3, -0.2, 0.5]}},
        "duration": 100.0}
LOADED = scene_from_mapping({**BODY, "loads": {"moment_space": [0.0, 0.15, 0.0]}}, source="bench")
FREE = scene_from_mapping(BODY, source="bench")
# (scheme, options, largest dt, halvings)
CANDIDATES = [
    ("rk4", {}, 0.05, 8),
    ("rkmk4", {}, 0.05, 8),
    ("splitting", {"composition": 6}, 0.2, 6),
    ("splitting", {"composition": 8}, 0.4, 5),
    ("midpoint", {"composition": 6}, 0.2, 6),
    ("exact_split", {"composition": 4}, 0.1, 6),
    ("exact_split", {"composition": 6}, 0.4, 6),
    ("exact_split", {"composition": 8}, 0.4, 5),
]


def final_state(scene, scheme, dt, options, copies=1):
    """(final quaternion, kernel CPU seconds per case)."""
    run = simulate([scene] * copies, scheme, dt, scene.duration, options)
    return run.quaternion[0, -1], run.output.kernel_cpu_seconds / copies


def cost_at(target, errors, seconds):
    """Seconds per case at ``target`` error, log-log between the bracketing runs; None if no
    run reaches it."""
    for k in range(1, len(errors)):
        if errors[k - 1] > target >= errors[k]:
            x = np.log(target / errors[k - 1]) / np.log(errors[k] / errors[k - 1])
            return float(np.exp(np.log(seconds[k - 1]) + x * np.log(seconds[k] / seconds[k - 1])))
    return None


def dop853_run(scene, reference):
    """(seconds, final orientation error against ``reference``) of DOP853 at 1e-13."""
    start = time.perf_counter()
    run = dop853.integrate(scene.state_row(), scene.param_row(), np.array([0.0, scene.duration]),
                           max_steps=10**7, halt=HALT_FLAG)
    seconds = time.perf_counter() - start
    return seconds, orientation_error(run.samples[-1, STATE_FIELDS["quaternion"]], reference)


def main():
    reference, _ = final_state(LOADED, "exact_split", 0.005, {"composition": 8})
    coarser, _ = final_state(LOADED, "exact_split", 0.01, {"composition": 8})
    dop853_seconds, dop853_error = dop853_run(LOADED, reference)
    print(f"loaded body, 100 s: reference exact_split composition 8 at dt 0.005 s; at dt 0.01 s "
          f"it differs by {orientation_error(coarser, reference):.1e} rad; DOP853 (1e-13) "
          f"differs by {dop853_error:.1e} rad and takes {dop853_seconds * 1e3:.0f} ms a case")
    header = "  ".join(f"at {target:g} rad" for target in TARGETS)
    print(f"{'scheme':28s} {'errors over the halved dt (rad)':>60s}  cost a case {header}")
    costs = {target: {} for target in TARGETS}
    for scheme, options, largest, count in CANDIDATES:
        name = scheme + "".join(f", composition {v}" for v in options.values())
        final_state(LOADED, scheme, largest, options)  # compile, or load from the cache
        errors, seconds = [], []
        for dt in largest / 2.0 ** np.arange(count):
            q, cost = final_state(LOADED, scheme, dt, options, copies=BATCH)
            errors.append(orientation_error(q, reference))
            seconds.append(cost)
        shown = []
        for target in TARGETS:
            costs[target][name] = cost_at(target, errors, seconds)
            shown.append("-" if costs[target][name] is None else
                         f"{costs[target][name] * 1e3:.3f} ms")
        print(f"{name:28s} {' '.join(f'{e:.1e}' for e in errors):>60s}  "
              + "  ".join(f"{text:>12s}" for text in shown))
    for target in TARGETS:
        reached = {name: cost for name, cost in costs[target].items() if cost is not None}
        best = min(reached, key=reached.get)
        rk4 = costs[target]["rk4"]
        versus_rk4 = f"{rk4 / reached[best]:.1f}x faster than rk4" if rk4 else "rk4 never reaches it"
        print(f"at {target:g} rad: best {best}, {reached[best] * 1e3:.3f} ms a case: {versus_rk4}, "
              f"{dop853_seconds / reached[best]:.0f}x faster than DOP853 (whose own error is "
              f"{dop853_error:.1e} rad)")

    exact = reference_solutions([FREE], np.array([0.0, FREE.duration]))[0].quaternion[-1]
    final_state(FREE, "exact_split", 100.0, {})
    q, one_step = final_state(FREE, "exact_split", 100.0, {}, copies=BATCH)
    free_dop853, free_error = dop853_run(FREE, exact)
    # the reference is the same closed form, so the difference is zero or an ulp: the tests
    # measure exact_split against a 40-digit solution instead (tests/test_compositions.py)
    print(f"free body, 100 s: exact_split in one step {one_step * 1e6:.1f} us a case, "
          f"{orientation_error(q, exact):.1e} rad off the exact reference (the same closed "
          f"form); DOP853 {free_dop853 * 1e3:.0f} ms, {free_error:.1e} rad off")


if __name__ == "__main__":
    main()
