"""Round-off over a long run, plain and compensated sums: run the study configs/round_off.yaml
(1e8 steps of splitting composed to order 8 on a free asymmetric body, option `compensated`
0 and 1), fit how its energy and orientation errors grow with the number of steps, and draw
docs/figures/round_off_growth.png (docs/results.md, "Round-off over 1e8 steps").

Usage: python pipelines/bench_round_off.py [RESULTS_DIR] [--steps N]
       python pipelines/bench_round_off.py --cost

``--cost`` measures instead what the option costs per step: for every scheme that has it,
body-steps per second of `rbstudy bench`'s scene (the Abaqus top, dt = 1e-4 s) for 1000
bodies on one core, plain and compensated in turn, `ROUNDS` times; it prints the medians.

RESULTS_DIR defaults to results/; an archive already there is reused (the sweep reuses its
batches). ``--steps`` runs a shorter study (the same dt, N steps, 1e4 samples) for a quick
look. The exponents are slopes of a log-log fit of each error's running maximum against the
step count over the last two decades of the run (and over all of it); Brouwer's law for a method whose
truncation is below the rounding is n^(1/2) for the energy and n^(3/2) for the angle.
"""

import argparse
import pathlib
import subprocess
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from rbstudy.numerics.driver import run_batch  # noqa: E402
from rbstudy.pipeline.bench import BENCH_DT, abaqus_top_scene  # noqa: E402
from rbstudy.schemes import BUILTIN  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "round_off.yaml"
FIGURE = ROOT / "docs" / "figures" / "round_off_growth.png"
DT = 0.02  # s, the study's step
SAMPLES = 10_000
# The fit covers the last two decades of steps: the first samples hold a handful of
# roundings, far from the statistics of the law.
FIT_DECADES = 2.0
# Brouwer's law, and how far a fitted exponent may sit from it (issue 33)
LAW = {"energy_error": 0.5, "orientation_error": 1.5}
TOLERANCE = 0.2
# --cost: bodies, steps of each and alternations
COST_BODIES, COST_STEPS, ROUNDS = 1000, 2000, 5


def growth_exponent(steps, errors, decades=None):
    """Slope of log(running max |error|) against log(steps), over the last ``decades`` of
    steps (None: the whole run)."""
    envelope = np.maximum.accumulate(np.abs(errors))
    fitted = envelope > 0
    if decades is not None:
        fitted &= steps >= steps[-1] / 10.0**decades
    return float(np.polyfit(np.log(steps[fitted]), np.log(envelope[fitted]), 1)[0])


def run_study(results, steps):
    """Sweep the study (shortened to ``steps`` when given); returns the archive's path and the
    wall time."""
    command = [sys.executable, "-m", "rbstudy.cli", "sweep", str(CONFIG), "--out", str(results), "--quiet"]
    if steps:
        duration = steps * DT
        command += [
            "--set",
            f"scene.duration={duration!r}",
            "--set",
            f"output.interval={duration / SAMPLES!r}",
        ]
    start = time.perf_counter()
    subprocess.run(command, check=True)
    return results / "round_off" / "round_off.nc", time.perf_counter() - start


def step_rate(scheme, scene, flag):
    """Body-steps per second of ``scheme`` with ``compensated`` = ``flag``, one core."""
    rows = lambda row: np.repeat(row[None, :], COST_BODIES, axis=0)  # noqa: E731
    options = rows(scheme.option_row({"compensated": flag}))
    out = run_batch(
        scheme,
        rows(scene.state_row()),
        rows(scene.param_row()),
        options,
        BENCH_DT,
        COST_STEPS,
        COST_STEPS,
        threads=1,
    )
    return out.results["n_steps"].sum() / out.kernel_seconds


def print_costs():
    """The option's cost per step, scheme by scheme (module docstring)."""
    scene = abaqus_top_scene()
    print(f"body-steps/s, {COST_BODIES} Abaqus tops x {COST_STEPS} steps, one core, median of {ROUNDS}")
    print(
        f"{'scheme':10s} {'plain':>10s} {'compensated':>12s} "
        f"{'ns/step plain':>14s} {'compensated':>12s} {'ratio':>6s}"
    )
    for name, scheme in BUILTIN.items():
        if "compensated" not in {option.name for option in scheme.options}:
            continue
        rates = {0: [], 1: []}
        for _ in range(ROUNDS):
            for flag in (0, 1):
                rates[flag].append(step_rate(scheme, scene, flag))
        plain, compensated = (float(np.median(rates[flag])) for flag in (0, 1))
        print(
            f"{name:10s} {plain:10.3e} {compensated:12.3e} {1e9 / plain:14.1f} {1e9 / compensated:12.1f} "
            f"{plain / compensated:6.2f}"
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="?", default="results", type=pathlib.Path)
    parser.add_argument("--steps", type=float, help="steps of a shorter run (default: the study's 1e8)")
    parser.add_argument("--cost", action="store_true", help="measure the option's cost per step")
    args = parser.parse_args()
    if args.cost:
        print_costs()
        return
    archive, seconds = run_study(args.results, int(args.steps) if args.steps else None)
    data = xr.open_dataset(archive, decode_times=False)  # seconds since the start
    steps = np.rint(data["time"].values / DT)
    later = steps > 0
    print(f"{archive}: {steps[-1]:.0e} steps, sweep {seconds:.0f} s wall")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for axis, name in zip(axes, LAW, strict=True):
        ends, exponents = {}, {}
        for flag in (0, 1):
            errors = np.abs(data[name].sel(compensated=flag).squeeze().values)
            whole = growth_exponent(steps[later], errors[later])
            exponents[flag] = growth_exponent(steps[later], errors[later], FIT_DECADES)
            ends[flag] = errors[-1]
            label = f"{'compensated' if flag else 'plain'}: ~n^{exponents[flag]:.2f}"
            axis.loglog(steps[later], errors[later], label=label, lw=1.0 if flag else 1.6)
            print(
                f"  {name:18s} {'compensated' if flag else 'plain':11s} end {errors[-1]:.2e}, "
                f"grows like n^{exponents[flag]:.2f} (last {FIT_DECADES:g} decades), n^{whole:.2f} (all)"
            )
        verdict = "no faster" if exponents[1] <= LAW[name] + TOLERANCE else "faster"
        print(
            f"  {name}: compensated ends {ends[0] / ends[1]:.0f}x below plain and grows {verdict} "
            f"than Brouwer's n^{LAW[name]} (+{TOLERANCE})"
        )
        guide = ends[1] * (steps[later] / steps[-1]) ** LAW[name]
        axis.loglog(steps[later], guide, "k:", lw=0.8, label=f"n^{LAW[name]} (Brouwer)")
        axis.set_xlabel("steps n")
        axis.set_ylabel(f"{data[name].attrs['long_name']} ({data[name].attrs['units']})")
        axis.legend(fontsize=8)
    fig.suptitle("splitting, composition 8, dt = 0.02 s, free body I = (1, 2, 3)", fontsize=10)
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=110)
    print(f"wrote {FIGURE}")


if __name__ == "__main__":
    main()
