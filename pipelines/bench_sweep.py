"""Print the sweep figures of docs/performance.md: the time each scheme takes to get ready in
a fresh process, the default study cold and warm, and how wall time, the share outside the
kernels and peak memory grow from 100 to 10,000 cases; with ``--scale``, studies of 200
steps a case up to a million cases.

Usage: python pipelines/bench_sweep.py [--sizes 100 1000 10000] [--scale 10000 100000 1000000]
       [--format netcdf zarr] [--workers N]

Every measurement runs `rbstudy sweep` in a fresh process (so that compilation and peak
memory are those a user sees) into a fresh results folder, with `--quiet`:

- wall: the process's wall time, imports and compilation included;
- kernel: the summed ``run_time`` of the dataset (core-seconds in the compiled driver);
- outside: ``1 - kernel / (wall x cores)``, the share of the machine's time not spent in
  kernels (compilation, references, outputs, files, scheduling);
- peak RSS: the process's maximum resident set size.

"Ready": `Scheme.ensure_compiled()` of every scheme, one after the other, in a fresh process
(what a sweep or a dask worker does before its first batch). "Cold" points numba at an
empty cache directory; "warm" reuses the cache filled by the cold
run. The scaling studies sweep ``inertia_ratio`` over N values with one scheme and one dt;
the last line is a kernel-heavy study (1,000 cases of 2e5 rk4 steps).

``--scale`` sweeps the default scene over 100 spins x N/100 tilts (each case its own scene),
200 leapfrog steps a case (dt 0.01 s, 2 s), 11 output times, and prints besides the
archive's size, the bytes the sweep wrote (``wchar`` of /proc/self/io: parts, archive and all),
the seconds xarray takes to open it lazily (``open_dataset``, nothing loaded) and the floor:
the kernels' core-seconds shared by the cores plus the archive's bytes at the disk's write
speed, measured first (1 GiB written and synced in the results' temporary folder). Each
size runs once per ``--format`` (the netCDF archive, the zarr store), with ``--workers N``
on a local cluster of N worker processes (which write a zarr store's regions themselves):
peak memory and bytes written are then the whole process tree's, sampled every 0.1 s.
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "configs" / "abaqus_top.yaml"

# The child process: run one sweep and report wall time, kernel core-seconds and peak RSS.
_CHILD = """
import json, os, pathlib, resource, sys, threading, time
import psutil
tree, peak, wrote = psutil.Process(), [0], {}
def sample():  # the whole tree's resident memory and bytes written: workers are processes
    while True:
        total = 0
        for process in [tree, *tree.children(recursive=True)]:
            try:
                total += process.memory_info().rss
                wrote[process.pid] = process.io_counters().write_chars
            except psutil.Error:
                pass
        peak[0] = max(peak[0], total)
        time.sleep(0.1)
threading.Thread(target=sample, daemon=True).start()
start = time.perf_counter()
from rbstudy.cli import main
code = main(["sweep", sys.argv[1], "--out", sys.argv[2], "--quiet", *sys.argv[3:]])
wall = time.perf_counter() - start
from rbstudy.archive.load import open_results
rss = max(peak[0], resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
wrote[os.getpid()] = tree.io_counters().write_chars
archive = next(path for path in pathlib.Path(sys.argv[2]).glob("*/*.*") if path.suffix in (".nc", ".zarr"))
files = [f for f in archive.rglob("*") if f.is_file()] if archive.is_dir() else [archive]
size = sum(f.stat().st_size for f in files)
import xarray
start = time.perf_counter()
xarray.open_dataset(archive, decode_times=False).close()
lazy = time.perf_counter() - start
dataset = open_results(archive, ["run_time", "status"])
print(json.dumps({"code": code, "wall": wall, "kernel": float(dataset.run_time.sum()),
                  "cases": int(dataset.status.size), "rss": rss, "lazy_open": lazy,
                  "archive": size, "written": sum(wrote.values())}))
"""


# The child process: get every scheme ready and report the seconds each took.
_READY = """
import json, time
from rbstudy.schemes import BUILTIN
seconds = {}
for name, scheme in BUILTIN.items():  # rbstudy's own, whatever else is installed
    start = time.perf_counter()
    scheme.ensure_compiled()
    seconds[name] = time.perf_counter() - start
print(json.dumps(seconds))
"""


def ready(env):
    done = subprocess.run([sys.executable, "-c", _READY], capture_output=True, text=True, env=env, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def measure(config, env=None, options=()):
    """The figures of one fresh ``rbstudy sweep config`` with the sweep ``options``."""
    with tempfile.TemporaryDirectory() as out:
        done = subprocess.run(
            [sys.executable, "-c", _CHILD, str(config), out, *options],
            capture_output=True,
            text=True,
            env=env,
            check=False,
        )
    if done.returncode:
        sys.exit(f"{config}: the sweep failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def scaling_config(folder, cases, scheme="leapfrog", dt=0.001):
    """The default scene over ``cases`` inertia ratios, one scheme, one dt."""
    study = yaml.safe_load(DEFAULT.read_text())
    study.update(name=f"scale{cases}", run={"scheme": scheme, "dt": dt})
    study["sweep"] = {"inertia_ratio": {"linspace": [0.1, 2.0, cases]}}
    path = pathlib.Path(folder) / f"scale{cases}_{scheme}_{dt:g}.yaml"
    path.write_text(yaml.safe_dump(study))
    return path


def scale_config(folder, cases):
    """The default scene over 100 spins x ``cases``/100 tilts, 200 leapfrog steps a case."""
    study = yaml.safe_load(DEFAULT.read_text())
    study.update(name=f"spin_tilt{cases}", run={"scheme": "leapfrog", "dt": 0.01}, output={"interval": 0.2})
    study["scene"]["duration"] = 2.0
    study["sweep"] = {
        "spin": {"logspace": [1, 100, 100]},
        "tilt": {"linspace": [1, 60, max(1, cases // 100)]},
    }
    path = pathlib.Path(folder) / f"spin_tilt{cases}.yaml"
    path.write_text(yaml.safe_dump(study))
    return path


def line(label, figures):
    cores = os.cpu_count() or 1
    outside = 1.0 - figures["kernel"] / (figures["wall"] * cores)
    return (
        f"{label:28s} {figures['cases']:7d} {figures['wall']:9.2f} {figures['kernel']:11.3f} "
        f"{100 * outside:8.1f}% {figures['rss'] / 2**20:9.0f}"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument(
        "--scale",
        type=int,
        nargs="+",
        metavar="CASES",
        help="only the 200-step studies of these sizes (multiples of 100)",
    )
    parser.add_argument(
        "--format",
        nargs="+",
        default=["netcdf"],
        choices=("netcdf", "zarr"),
        help="--scale's archive formats",
    )
    parser.add_argument("--workers", type=int, help="--scale's studies on a local cluster of N workers")
    args = parser.parse_args()
    if args.scale:
        scale(args.scale, args.format, args.workers)
        return
    print(f"rbstudy sweep figures, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d')}")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        cold, warm = ready(env), ready(env)
    print(f"{'scheme ready in a fresh process':32s} {'cold s':>8s} {'warm s':>8s}")
    for name in cold:
        print(f"{name:32s} {cold[name]:8.3f} {warm[name]:8.3f}")
    print(f"{'all':32s} {sum(cold.values()):8.2f} {sum(warm.values()):8.2f}")
    print(f"{'study':28s} {'cases':>7s} {'wall s':>9s} {'kernel cs':>11s} {'outside':>9s} {'peak MiB':>9s}")
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as configs:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        print(line("abaqus_top (numba cold)", measure(DEFAULT, env)), flush=True)
        print(line("abaqus_top (numba warm)", measure(DEFAULT, env)), flush=True)
        for cases in args.sizes:
            figures = measure(scaling_config(configs, cases), env)
            print(line("leapfrog, dt 1e-3, 2 s", figures), flush=True)
        # Enough kernel work per case for the fixed costs to fade (2e5 steps a case).
        figures = measure(scaling_config(configs, 1000, "rk4", 1e-5), env)
        print(line("rk4, dt 1e-5, 2 s", figures), flush=True)


def disk_speed(size=2**30, block=2**24):
    """Bytes a second this machine's temporary folder takes, written and synced."""
    data = os.urandom(block)
    with tempfile.TemporaryDirectory() as folder:
        path = pathlib.Path(folder) / "speed"
        start = time.perf_counter()
        with open(path, "wb") as file:
            for _ in range(size // block):
                file.write(data)
            file.flush()
            os.fsync(file.fileno())
        return size / (time.perf_counter() - start)


def scale(sizes, formats, workers):
    speed = disk_speed()
    cores = os.cpu_count() or 1
    print(f"disk write speed {speed / 1e9:.2f} GB/s, {cores} cores")
    on = ("--workers", str(workers)) if workers else ()
    print(
        f"{'200 leapfrog steps a case':28s} {'cases':>7s} {'wall s':>9s} {'kernel cs':>11s} "
        f"{'outside':>9s} {'peak MiB':>9s} {'archive MiB':>12s} {'written GiB':>12s} "
        f"{'lazy open s':>12s} {'floor s':>8s} {'x floor':>8s}"
    )
    with tempfile.TemporaryDirectory() as configs:
        for cases in sizes:
            for archive in formats:
                figures = measure(scale_config(configs, cases), options=("--format", archive, *on))
                floor = figures["kernel"] / cores + figures["archive"] / speed
                label = f"spin x tilt, {archive}" + (f", {workers} workers" if workers else "")
                print(
                    f"{line(label, figures)} {figures['archive'] / 2**20:12.1f} "
                    f"{figures['written'] / 2**30:12.2f} {figures['lazy_open']:12.2f} {floor:8.2f} "
                    f"{figures['wall'] / floor:8.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
