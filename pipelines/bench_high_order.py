"""Print the work-precision figures of docs/performance.md: the cost per case at which each
scheme reaches a final orientation error of 1e-8, 1e-10 and 1e-12 rad after 100 s on an
asymmetric body under a space-fixed moment, side by side with DOP853; and the free body,
which `exact_split` integrates in a single step.

Usage: python pipelines/bench_high_order.py [--batch 16] [--only "splitting, composition 8" ...]

``--batch`` sets the copies of the case each cost is measured on (16 by default: the
single-body loop); at 16 or more a block scheme steps its bodies in blocks across SIMD
lanes, so a batch of 1e4, as a large study runs them, costs less a case (DOP853 runs case
by case at any batch). ``--only`` measures the named candidates alone (as the table names
them), for a large batch.

The body is I = (1, 2, 3), w0 = (0.6, 1.5, 0.9) rad/s, from the rotation vector
(0.3, -0.2, 0.5), under M = (0, m, 0) N m in space axes: m = 0.15 (the moment pumps the spin
from 1.85 to 8.6 rad/s) and m = 0.02 (a milder one). The reference is the test suite's
extended-precision solution (tests/extended_oracle.py: extrapolation in 80-bit floats,
sharing no code with the kernels) at macro steps of 0.02 s, checked against 0.04 s. Each
scheme runs over halved steps; the cost at a target is interpolated log-log between the two
runs that bracket it, from the kernel CPU time of a batch of 16 copies of the case
(compilation done first), per case. With plain sums errors level off at 1e-12 to 1e-11 rad,
every scheme's rounding over 1e3-1e5 steps amplified by the motion; the compensated
candidates (option `compensated`) level off at 1e-14 to 2e-13 and reach 1e-12. rk4 is
compared at its best, plain or compensated.
"""

import argparse
import pathlib
import sys
import time
import warnings

import numpy as np

from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics.driver import HALT_FLAG
from rbstudy.numerics.state import STATE_FIELDS
from rbstudy.physics.metrics import orientation_error
from rbstudy.physics.references import reference_solutions
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import dop853

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from extended_oracle import loaded_rotation  # noqa: E402

# rad, final orientation errors
TARGETS = (1e-8, 1e-10, 1e-12)
# DOP853 at its tightest: scipy floors rtol at 100 eps (2.2e-14, with a warning) and takes
# atol as given; tighter tolerances change neither its error nor its cost
TIGHTEST = 1e-14
BATCH = 16
BODY = {
    "body": {"inertia": [1.0, 2.0, 3.0]},
    "initial": {
        "angular_velocity": {"body": [0.6, 1.5, 0.9]},
        "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
    },
    "duration": 100.0,
}
MOMENTS = (0.15, 0.02)  # N m about the space y axis
FREE = scene_from_mapping(BODY, source="bench")
# (scheme, options, largest dt, halvings)
CANDIDATES = [
    ("rk4", {}, 0.05, 10),
    ("rkmk4", {}, 0.05, 8),
    ("splitting", {"composition": 6}, 0.2, 6),
    ("splitting", {"composition": 8}, 0.4, 5),
    ("midpoint", {"composition": 6}, 0.2, 6),
    ("exact_split", {"composition": 4}, 0.1, 6),
    ("exact_split", {"composition": 6}, 0.4, 6),
    ("exact_split", {"composition": 8}, 0.4, 5),
    # compensated sums (issue 33): the rounding floor of the plain runs moves down
    ("rk4", {"compensated": 1}, 0.05, 10),
    ("splitting", {"composition": 8, "compensated": 1}, 0.4, 6),
    ("exact_split", {"composition": 6, "compensated": 1}, 0.4, 6),
    ("exact_split", {"composition": 8, "compensated": 1}, 0.4, 6),
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


def dop853_run(scene, reference, tolerance=dop853.RTOL):
    """(seconds, final orientation error against ``reference``) of DOP853 at rtol = atol =
    ``tolerance`` (the scheme's 1e-13 by default), its right-hand side compiled first (a cold
    cache would add seconds); CPU seconds of this thread, as the kernels' are, so that a
    shared machine slows neither side's figure."""
    dop853.integrate(
        scene.state_row(), scene.param_row(), np.array([0.0, 1e-3]), max_steps=10, halt=HALT_FLAG
    )
    start = time.thread_time()
    run = dop853.integrate(
        scene.state_row(),
        scene.param_row(),
        np.array([0.0, scene.duration]),
        max_steps=10**7,
        halt=HALT_FLAG,
        tolerance=tolerance,
    )
    seconds = time.thread_time() - start
    return seconds, orientation_error(run.samples[-1, STATE_FIELDS["quaternion"]], reference)


def extended(scene, moment, step):
    """The extended-precision final orientation of ``scene`` under ``moment``."""
    return loaded_rotation(
        scene.body.inertia,
        scene.quaternion,
        scene.omega_body,
        scene.duration,
        step,
        moment_space=(0.0, moment, 0.0),
    )[0]


def _name(scheme, options):
    return scheme + "".join(f", {key} {value}" for key, value in options.items())


def loaded_table(moment, candidates, batch):
    """Print the errors and costs of ``candidates`` under ``moment``, each cost a case in a
    batch of ``batch`` copies, and the best at each target against rk4 and DOP853."""
    scene = scene_from_mapping({**BODY, "loads": {"moment_space": [0.0, moment, 0.0]}}, source="bench")
    reference = extended(scene, moment, 0.02)
    check = orientation_error(extended(scene, moment, 0.04), reference)
    dop853_seconds, dop853_error = dop853_run(scene, reference)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy's "rtol too small": it floors it, as said
        tightest_seconds, tightest_error = dop853_run(scene, reference, TIGHTEST)
    print(
        f"\nspace moment (0, {moment:g}, 0) N m, 100 s: reference in extended precision "
        f"(macro step 0.02 s; 0.04 s differs by {check:.1e} rad); DOP853 (1e-13) is "
        f"{dop853_error:.1e} rad off and takes {dop853_seconds * 1e3:.0f} ms a case; at its "
        f"tightest ({TIGHTEST:g}) {tightest_error:.1e} rad off in {tightest_seconds * 1e3:.0f} ms"
    )
    targets = (*TARGETS, dop853_error, tightest_error)
    header = "  ".join(f"at {target:.2g}" for target in targets)
    print(f"{'scheme':40s} {'errors over the halved dt (rad)':>60s}  cost a case (B = {batch}) {header}")
    costs = {target: {} for target in targets}
    for scheme, options, largest, count in candidates:
        name = _name(scheme, options)
        final_state(scene, scheme, largest, options, copies=batch)  # compile, or load from the cache
        errors, seconds = [], []
        for dt in largest / 2.0 ** np.arange(count):
            q, cost = final_state(scene, scheme, dt, options, copies=batch)
            errors.append(orientation_error(q, reference))
            seconds.append(cost)
        shown = []
        for target in targets:
            costs[target][name] = cost_at(target, errors, seconds)
            shown.append("-" if costs[target][name] is None else f"{costs[target][name] * 1e3:.3f} ms")
        print(
            f"{name:40s} {' '.join(f'{e:.1e}' for e in errors):>60s}  "
            + "  ".join(f"{text:>12s}" for text in shown)
        )
    for target in targets:
        reached = {name: cost for name, cost in costs[target].items() if cost is not None}
        if not reached:
            print(f"at {target:.2g} rad: no scheme reaches it")
            continue
        best = min(reached, key=reached.get)
        # rk4 at its best, plain or compensated
        rk4 = min((cost for name, cost in reached.items() if name.split(",")[0] == "rk4"), default=None)
        measured_rk4 = any(scheme == "rk4" for scheme, *_ in candidates)
        versus_rk4 = (
            f"{rk4 / reached[best]:.1f}x faster than rk4"
            if rk4
            else ("rk4 never reaches it" if measured_rk4 else "rk4 not measured")
        )
        # DOP853 at the target: at its tightest where that reaches it, else out of its reach
        if target >= dop853_error:
            versus_dop853 = f"{dop853_seconds / reached[best]:.0f}x faster than DOP853 at 1e-13"
        elif target >= tightest_error:
            versus_dop853 = f"{tightest_seconds / reached[best]:.0f}x faster than DOP853 at its tightest"
        else:
            versus_dop853 = (
                f"DOP853 never gets there (its tightest: {tightest_error:.1e} rad; "
                f"{tightest_seconds / reached[best]:.0f}x this case's time)"
            )
        cost = f"{reached[best] * 1e3:.3f} ms a case"
        print(f"at {target:.2g} rad: best {best}, {cost}: {versus_rk4}, {versus_dop853}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=BATCH, help="copies of the case a cost is measured on")
    parser.add_argument(
        "--only", action="append", default=[], help="a candidate's name, as the table gives it"
    )
    args = parser.parse_args()
    candidates = [c for c in CANDIDATES if not args.only or _name(c[0], c[1]) in args.only]
    unknown = set(args.only) - {_name(c[0], c[1]) for c in CANDIDATES}
    if unknown:
        sys.exit(
            f"--only: no candidate {sorted(unknown)}; they are {[_name(c[0], c[1]) for c in CANDIDATES]}"
        )
    for moment in MOMENTS:
        loaded_table(moment, candidates, args.batch)

    print()
    exact = reference_solutions([FREE], np.array([0.0, FREE.duration]))[0].quaternion[-1]
    final_state(FREE, "exact_split", 100.0, {})
    q, one_step = final_state(FREE, "exact_split", 100.0, {}, copies=BATCH)
    free_dop853, free_error = dop853_run(FREE, exact)
    # the reference is the same closed form, so the difference is zero or an ulp: the tests
    # measure exact_split against a 40-digit solution instead (tests/test_compositions.py)
    print(
        f"free body, 100 s: exact_split in one step {one_step * 1e6:.1f} us a case, "
        f"{orientation_error(q, exact):.1e} rad off the exact reference (the same closed "
        f"form); DOP853 {free_dop853 * 1e3:.0f} ms, {free_error:.1e} rad off"
    )


if __name__ == "__main__":
    main()
