"""Each scheme's cost per body-step on this machine: measured once, cached, and the cost
model of the findings and the forecast.

A case's kernel time (``run_time``) on a small study is microseconds, mostly timer noise:
costed by it, the default study's recommendation changed between two runs of the same
study. The cost model instead is a case's steps times its scheme's seconds per body-step,
measured here once per machine and source tree, so that every run of a study on it costs
its cases alike; the archive stores the figure of each case's run (``step_seconds``) and its
relative uncertainty, from which the findings cost a case without rerunning anything.

A scheme is measured through `rbstudy.numerics.driver.run_batch`, the path a study's batch
takes (an engine's adapter included): `CALIBRATION_BODIES` Abaqus tops (docs/theory.md s2)
at `CALIBRATION_DT`, one thread, its CPU time per step actually taken. The steps double from
`FIRST_STEPS` until a run takes `MIN_SECONDS`, so that the process timer's tick is a small
share; then `REPEATS` runs at those steps give the median and the uncertainty: half the
spread of the runs relative to the median, at least `BETWEEN_CALIBRATIONS`. The schemes
of a calibration are measured in rounds, a run of each per round.

The figures are cached in ``calibration.json`` in numba's cache folder
(`rbstudy.numerics.jit.cache_dir`, named after the source digest: an edit of the sources
gets an empty cache, so the kernels are measured again), under a key of the machine
(`machine_key`) and, per scheme, its name, provider and code digest (a plug-in's sources, an
engine's version). A scheme not measured yet, or adaptive (dop853, whose cost per step depends
on its output grid), costs its declared `Scheme.step_seconds`, with an unknown uncertainty.

DOP853 as the references run it (`reference_cost`: sampled at far fewer times than it steps)
is measured alike, once its right-hand side is compiled: `dop853.integrate` on the Abaqus top
under a space moment, sampled at its ends only, its CPU time per accepted step, and cached
under its own key.
"""

import contextlib
import json
import math
import os
import platform
import tempfile
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rbstudy.numerics.driver import run_batch
from rbstudy.numerics.jit import cache_dir
from rbstudy.pipeline.bench import abaqus_top_scene
from rbstudy.pipeline.progress import Progress
from rbstudy.schemes import Scheme, dop853, get_scheme

__all__ = [
    "StepCost",
    "calibrate",
    "reference_cost",
    "step_cost",
    "cached",
    "measure",
    "machine_key",
    "calibration_path",
    "compile_seconds",
    "record_compile",
    "CALIBRATION_BODIES",
    "REPEATS",
]

# A study's batch holds the cases of one scheme and dt: the default study's, four bodies (its
# four inertia ratios). Fewer than a block of SIMD lanes (16), so a body steps as in most
# small studies; and an engine's per-call cost per step is shared as in them.
CALIBRATION_BODIES = 4
CALIBRATION_DT = 1e-4  # s, `rbstudy bench`'s: the first-order schemes stay below blow-up
FIRST_STEPS = 64
MAX_STEPS = 2**22
# A run this long in CPU time (s): the process timer's tick (~1e-6 s to 1e-2 s by system) is
# then at most a few percent of it, and a scheme's measurement takes ~REPEATS times this.
MIN_SECONDS = 0.01
REPEATS = 5
# The least relative uncertainty of a figure: the spread of one calibration's rounds (0.4-8%)
# understates how far another calibration lands. Four calibrations one after another on the
# 2-core machine at load 4 (docs/performance.md) gave rk4 1.7-2.4e-7 s, euler 0.9-1.1e-7 s,
# midpoint 1.9-2.2e-7 s, rkmk4 3.0-3.7e-7 s: 8-18% about their middle.
BETWEEN_CALIBRATIONS = 0.1
# Output samples every this many steps, as a study at dt = interval / 8 samples.
SAMPLE_EVERY = 8
# The scene `reference_cost` integrates: the Abaqus top under this space moment (N m), so
# that its right-hand side evaluates a load as a reference's does.
REFERENCE_MOMENT = (0.0, 0.1, 0.0)
_FILE = "calibration.json"
_COMPILE_FILE = "compile_seconds.json"


@dataclass(frozen=True)
class StepCost:
    """A scheme's core-seconds per body-step (``seconds``) and its relative uncertainty
    (``uncertainty``; NaN for a declared figure, never measured here)."""

    seconds: float
    uncertainty: float

    @property
    def calibrated(self) -> bool:
        return math.isfinite(self.uncertainty)


def calibration_path() -> str:
    """The cache file: ``calibration.json`` beside the compiled kernels."""
    return os.path.join(cache_dir(), _FILE)


def machine_key() -> str:
    """This machine, as the cache knows it: host, processor and the cores the process may
    use (a home folder shared by a cluster's nodes holds one figure per kind of node)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    parts = (platform.node(), platform.machine(), platform.processor(), f"{cores} cores")
    return " ".join(part for part in parts if part)


def _scheme_key(scheme: Scheme) -> str:
    return " ".join(filter(None, (scheme.name, scheme.origin, scheme.code_digest)))


def compile_path() -> str:
    """The file of the seconds each scheme took to compile, beside numba's caches of every
    source tree (`compile_seconds`: an edit of the sources compiles them all again, in about
    the time they took before)."""
    return os.path.join(os.path.dirname(cache_dir()), _COMPILE_FILE)


def compile_seconds() -> dict[str, float]:
    """The seconds each scheme took to compile on this machine the last time, name -> s."""
    return {name: float(s) for name, s in _read(compile_path()).items() if isinstance(s, (int, float))}


def record_compile(took: Mapping[str, float]) -> None:
    """Keep the seconds each scheme of ``took`` (name -> s) took to compile."""
    _write({name: seconds for name, seconds in took.items() if math.isfinite(seconds)}, compile_path())


# (path, modification time) -> figures: the forecast asks once a batch
_read_memo: dict[tuple[str, int], dict[str, Any]] = {}


def _read(path: str | None = None) -> dict[str, Any]:
    """The figures of this machine in the cache file ``path`` (the calibration's by
    default): scheme key -> its figures."""
    path = path or calibration_path()
    try:
        stamp = (path, os.stat(path).st_mtime_ns)
        if stamp not in _read_memo:
            with open(path, encoding="utf-8") as file:
                stored = json.load(file)
            figures = stored.get(machine_key(), {}) if isinstance(stored, dict) else {}
            for older in [key for key in _read_memo if key[0] == path]:
                del _read_memo[older]
            _read_memo[stamp] = figures if isinstance(figures, dict) else {}
        return _read_memo[stamp]
    except (OSError, ValueError):
        return {}


def _write(figures: Mapping[str, Any], path: str | None = None) -> None:
    """Merge ``figures`` (scheme key -> its figures) into the cache file ``path`` (the
    calibration's by default), replaced whole by a rename; a cache that cannot be written
    costs a measurement next time, nothing else."""
    path = path or calibration_path()
    with contextlib.suppress(OSError):
        try:
            with open(path, encoding="utf-8") as file:
                stored = json.load(file)
        except (OSError, ValueError):
            stored = {}
        if not isinstance(stored, dict):
            stored = {}
        stored.setdefault(machine_key(), {}).update(figures)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        handle, temporary = tempfile.mkstemp(
            dir=os.path.dirname(path), prefix=f".{os.path.basename(path)}.", suffix=".tmp"
        )
        try:
            with os.fdopen(handle, "w", encoding="utf-8") as file:
                json.dump(stored, file, indent=1, sort_keys=True)
            os.replace(temporary, path)
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temporary)


def cached(scheme: Scheme) -> StepCost | None:
    """The `StepCost` of ``scheme`` (a `rbstudy.schemes.Scheme`) cached for this machine, or
    None."""
    figure: Any = _read().get(_scheme_key(scheme))
    try:  # a cache edited by hand, or by another version: measured again
        cost = StepCost(float(figure["seconds"]), float(figure["uncertainty"]))
    except (TypeError, KeyError, ValueError):
        return None
    return cost if 0 < cost.seconds < math.inf and 0 <= cost.uncertainty < math.inf else None


def _run_seconds(scheme: Scheme, rows: tuple[np.ndarray, ...], n_steps: int) -> tuple[float, int]:
    """(CPU seconds, body-steps taken) of one run of ``n_steps`` steps of ``rows`` (state0,
    params, options)."""
    state0, params, options = rows
    out = run_batch(
        scheme,  # type: ignore[arg-type]  # numerics.driver.BatchKernel declares settable members; a Scheme is frozen
        state0,
        params,
        options,
        CALIBRATION_DT,
        n_steps,
        min(SAMPLE_EVERY, n_steps),
        threads=1,
    )
    return out.kernel_cpu_seconds, max(1, int(out.results["n_steps"].sum()))


def _prepared(scheme: Scheme) -> tuple[tuple[np.ndarray, ...], int]:
    """(rows, steps): the calibration batch of ``scheme`` and the steps a run of it takes to
    last `MIN_SECONDS` (its kernels compiled or loaded first, outside the clock)."""
    scheme.ensure_compiled()
    scene = abaqus_top_scene()
    rows = tuple(
        np.repeat(row[None, :], CALIBRATION_BODIES, axis=0)
        for row in (scene.state_row(), scene.param_row(), scheme.option_row())
    )
    steps = FIRST_STEPS
    while _run_seconds(scheme, rows, steps)[0] < MIN_SECONDS and steps < MAX_STEPS:
        steps *= 2
    return rows, steps


def measure(schemes: Sequence[Scheme]) -> dict[str, tuple[StepCost, float]]:
    """Measure the `StepCost` of each of ``schemes`` (`rbstudy.schemes.Scheme`) on this
    machine, in rounds of one run each: a change of load meanwhile falls on every scheme
    alike, and shows in each one's spread. Returns name -> (`StepCost`, seconds it took); a
    scheme whose kernel fails is left out (and costs its declared figure)."""
    prepared, took = {}, {}
    for scheme in schemes:
        started = time.perf_counter()
        try:
            prepared[scheme.name] = _prepared(scheme)
        except Exception:  # noqa: BLE001 - a plug-in's failing kernel fails in its batch, which says why
            continue
        took[scheme.name] = time.perf_counter() - started
    schemes = [scheme for scheme in schemes if scheme.name in prepared]
    rates: dict[str, list[float]] = {scheme.name: [] for scheme in schemes}
    for _ in range(REPEATS):
        for scheme in schemes:
            clock = time.perf_counter()
            seconds, taken = _run_seconds(scheme, *prepared[scheme.name])
            rates[scheme.name].append(seconds / taken)
            took[scheme.name] += time.perf_counter() - clock
    result = {}
    for name, runs in rates.items():
        median = float(np.median(runs))
        spread = float(np.max(runs) - np.min(runs)) / 2 / median
        result[name] = (StepCost(median, max(spread, BETWEEN_CALIBRATIONS)), took[name])
    return result


def calibrate(names: Iterable[str], progress: Progress | None = None) -> dict[str, StepCost | None]:
    """The `StepCost` of each fixed-step scheme of ``names``: cached, else measured now and
    cached (said on ``progress``, a `rbstudy.pipeline.progress.Progress`); name -> `StepCost`."""
    # an adaptive scheme's (dop853's) cost per step taken depends on how densely it samples:
    # at the calibration's output, every 8 steps of 1e-4 s, ~4x a study's; its declared figure
    costs = {name: cached(get_scheme(name)) for name in sorted(names) if not get_scheme(name).adaptive}
    missing = [get_scheme(name) for name, cost in costs.items() if cost is None]
    if not missing:
        return costs
    if progress is not None:
        progress.phase(f"calibrating the cost of a step of {len(missing)} schemes (once per machine)")
    measured = measure(missing)
    _write(
        {
            _scheme_key(scheme): {
                "seconds": measured[scheme.name][0].seconds,
                "uncertainty": measured[scheme.name][0].uncertainty,
                "measured_in_s": round(measured[scheme.name][1], 3),
            }
            for scheme in missing
            if scheme.name in measured
        }
    )
    return costs | {name: cost for name, (cost, _) in measured.items()}


def step_cost(scheme: Scheme, options: Mapping[str, Any] | None = None) -> StepCost:
    """The `StepCost` of a body-step of ``scheme`` with ``options`` (name -> value): its
    calibrated figure (`cached`) times what the options cost (a composition's stages,
    `rbstudy.schemes.Scheme.seconds_per_step`), else its declared one."""
    declared = scheme.seconds_per_step(options)
    figure = cached(scheme)
    if figure is None:
        return StepCost(declared, math.nan)
    # the options' factor first: exactly 1 without options that cost, so the figure as cached
    return StepCost(figure.seconds * (declared / scheme.step_seconds), figure.uncertainty)


def _reference_seconds(y0: np.ndarray, p: np.ndarray, n_steps: int) -> tuple[float, int]:
    """(CPU seconds, accepted steps) of one `dop853.integrate` of ``n_steps`` steps of state row
    ``y0`` with parameter row ``p``, sampled at its start only (as a reference samples: every
    many steps)."""
    started = time.process_time()
    run = dop853.integrate(y0, p, np.array([0.0, 1e9]), max_steps=n_steps)
    return time.process_time() - started, max(1, run.steps)


def reference_cost() -> StepCost:
    """The `StepCost` of an accepted step of DOP853 as the integrated references run it: cached
    for this machine, else measured now (`FIRST_STEPS` doubled until a run takes
    `MIN_SECONDS`, then `REPEATS` runs) if its right-hand side is compiled already, else the
    declared `Scheme.step_seconds` of `dop853`."""
    scheme = get_scheme("dop853")
    key = f"{_scheme_key(scheme)} reference"
    figure: Any = _read().get(key)
    with contextlib.suppress(TypeError, KeyError, ValueError):
        cost = StepCost(float(figure["seconds"]), float(figure["uncertainty"]))
        if 0 < cost.seconds < math.inf and 0 <= cost.uncertainty < math.inf:
            return cost
    if not scheme.is_cached():  # compiling it here would cost the forecast seconds
        return StepCost(scheme.step_seconds, math.nan)
    clock = time.perf_counter()
    scene = abaqus_top_scene({"moment_space": list(REFERENCE_MOMENT)})
    y0, p = scene.state_row(), scene.param_row()
    steps = FIRST_STEPS
    while _reference_seconds(y0, p, steps)[0] < MIN_SECONDS and steps < MAX_STEPS:
        steps *= 2
    rates = [seconds / taken for seconds, taken in (_reference_seconds(y0, p, steps) for _ in range(REPEATS))]
    median = float(np.median(rates))
    cost = StepCost(median, max(float(np.ptp(rates)) / 2 / median, BETWEEN_CALIBRATIONS))
    _write(
        {
            key: {
                "seconds": cost.seconds,
                "uncertainty": cost.uncertainty,
                "measured_in_s": round(time.perf_counter() - clock, 3),
            }
        }
    )
    return cost
