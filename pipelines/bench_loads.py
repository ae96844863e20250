"""Print the loads figures of docs/performance.md: body-steps per second of a few schemes on
the free Abaqus top; on the same top pushed by a space-fixed force at a node off its centre
of mass (whose moment the kernels turn with the body at every evaluation); and on that top
with the force tabulated in time (interpolated by the kernels at every evaluation).

Usage: python pipelines/bench_loads.py [--free-only] [--bodies 10000] [--steps 1000]

Each figure is ``bodies x steps`` over the kernel time of one `run_batch` call on every core
(compilation done first), three runs each. ``--free-only`` skips the loaded tops, so that the
script also runs on a revision older than loads at nodes (``PYTHONPATH=<that checkout>``):
compare before and after in one sitting.
"""

import argparse

import numpy as np

from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics.driver import run_batch
from rbstudy.schemes import get_scheme

SCHEMES = ("leapfrog", "rk4", "midpoint", "hht")
FREE = {
    "body": {"inertia": [1.0, 1.0, 2.0]},
    "initial": {"angular_velocity": {"body": [0.25, 0.0, 6.283185307179586]}},
}
# a small force, so that the top stays close to the free one over the run
PUSHED = {
    **FREE,
    "nodes": {"a": [0.5, 0.2, 0.1]},
    "loads": {"nodes": {"a": {"force_space": [0.0, 0.0, -1e-3]}}},
}
# the same force, ramped up over a table of 11 knots that spans the run
TIMED = {
    **FREE,
    "nodes": {"a": [0.5, 0.2, 0.1]},
    "loads": {
        "nodes": {"a": {"force_space": {"table": [[0.01 * k, 0.0, 0.0, -1e-4 * k] for k in range(11)]}}}
    },
}
DT = 1e-4
RUNS = 3


def rates(scene, name, bodies, steps):
    """Body-steps per second of ``RUNS`` batches of ``bodies`` copies of ``scene``."""
    scheme = get_scheme(name)
    state0 = np.repeat(scene.state_row()[None], bodies, axis=0)
    params = np.repeat(scene.param_row()[None], bodies, axis=0)  # the same width each
    options = np.repeat(scheme.option_row(None)[None], bodies, axis=0)
    run_batch(scheme, state0[:1], params[:1], options[:1], DT, 1, 1)  # compile
    return [
        bodies * steps / run_batch(scheme, state0, params, options, DT, steps, steps).kernel_seconds
        for _ in range(RUNS)
    ]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--free-only", action="store_true")
    parser.add_argument("--bodies", type=int, default=10_000)
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args()
    scenes = {"free top": FREE} if args.free_only else {"free top": FREE, "pushed": PUSHED, "timed": TIMED}
    for label, spec in scenes.items():
        scene = scene_from_mapping(spec)
        for name in SCHEMES:
            figures = " ".join(f"{r:.3g}" for r in rates(scene, name, args.bodies, args.steps))
            print(f"{label:9s} {name:9s} {figures}")


if __name__ == "__main__":
    main()
