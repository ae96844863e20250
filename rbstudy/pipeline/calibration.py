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
share. The schemes of a calibration are then measured in rounds, a run of each per round.

Other programs change the figures, and not alike: on the 2-core machine, with the other core
busy, rk4's step cost half as much again and hht's barely more, which reordered the
recommendation. So each round notes how many cores other programs kept busy meanwhile
(`others_cores`, from the system's CPU counters), and a round past `QUIET_CORES` does not
count: the rounds go on, a short pause between them, until `REPEATS` quiet ones, or
`MAX_ROUNDS`. A scheme's figure is the least of its quiet runs (noise only adds time), its
uncertainty half their spread relative to it, at least `BETWEEN_CALIBRATIONS`. Where the
machine stayed busy, the figure is the least of every run, its uncertainty
`rbstudy.archive.variables.BUSY_UNCERTAINTY`, so that the findings count as ties the costs a
busy machine cannot tell apart; it is cached as measured under load, and the next process that calibrates
measures it again.

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
import textwrap
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rbstudy.archive.variables import BUSY_UNCERTAINTY
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
# Cores other programs may keep busy during a round that counts: a quarter of one.
QUIET_CORES = 0.25
# Rounds at most (a busy machine's measurement ends there), and the pause after a busy one (s).
MAX_ROUNDS = 4 * REPEATS
BUSY_PAUSE = 0.2
# The least time over which a round's load is counted (s): the system counts busy time in
# ticks of 1-10 ms per core, so a window of a few ticks could not tell a busy core from an
# idle one. A shorter round is followed by a wait that fills the window.
LOAD_WINDOW = 0.2
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
    (``uncertainty``; NaN for a declared figure, never measured here); ``loaded`` where it was
    measured while other programs kept the machine busy."""

    seconds: float
    uncertainty: float
    loaded: bool = False

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


def _busy_seconds() -> float | None:
    """The seconds the cores this process may run on have been busy since boot (Linux's
    /proc/stat: every state but idle and waiting on I/O, the time the hypervisor gave the
    core to others included), or None where the system does not say."""
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    try:
        with open("/proc/stat", encoding="ascii") as file:
            lines = [line.split() for line in file if line.startswith("cpu")]
        rows = [row for row in lines if row[0] != "cpu" and (cores is None or int(row[0][3:]) in cores)]
        ticks = [[int(value) for value in row[1:9]] for row in rows]
        busy = sum(sum(row) - row[3] - row[4] for row in ticks)
        return busy / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def load_mark() -> tuple[float | None, float, float]:
    """A mark to count other programs' load from (`others_cores`): the cores' busy seconds
    (None where the system does not count them), this process's CPU seconds, the wall clock."""
    return _busy_seconds(), time.process_time(), time.perf_counter()


def others_cores(mark: tuple[float | None, float, float]) -> float:
    """How many cores programs other than this process kept busy, on average, since ``mark``
    (`load_mark`); 0.0 where the system does not say."""
    busy, own, wall = load_mark()
    if busy is None or mark[0] is None or wall <= mark[2]:
        return 0.0
    return max(0.0, (busy - mark[0]) - (own - mark[1])) / (wall - mark[2])


def _quiet_round(run_round: Callable[[], dict[str, float]]) -> tuple[dict[str, float], bool]:
    """Run ``run_round()`` and return its value and whether the machine was quiet meanwhile:
    other programs kept at most `QUIET_CORES` busy over at least `LOAD_WINDOW`; after a busy
    round, a pause of `BUSY_PAUSE`."""
    mark = load_mark()
    value = run_round()
    waited = LOAD_WINDOW - (time.perf_counter() - mark[2])
    if waited > 0:
        time.sleep(waited)
    quiet = others_cores(mark) <= QUIET_CORES
    if not quiet:
        time.sleep(BUSY_PAUSE)
    return value, quiet


def _rate(seconds: float, taken: int) -> float:
    return seconds / taken


def _rates_in_rounds(runs: Mapping[str, Callable[[], tuple[float, int]]]) -> dict[str, StepCost]:
    """Each run's seconds per step, in rounds of one run each (``runs``: name -> a function
    that runs once and returns (seconds, steps taken)) until `REPEATS` quiet rounds
    (`_quiet_round`) or `MAX_ROUNDS`; name -> `StepCost` (module docstring)."""

    def run_round():
        return {name: _rate(*run()) for name, run in runs.items()}

    quiet, every = [], []
    for _ in range(MAX_ROUNDS):
        rates, was_quiet = _quiet_round(run_round)
        every.append(rates)
        if was_quiet:
            quiet.append(rates)
            if len(quiet) == REPEATS:
                break
    loaded = len(quiet) < REPEATS
    costs = {}
    for name in runs:
        figures = [rates[name] for rates in (every if loaded else quiet)]
        least = min(figures)
        spread = (max(figures) - least) / 2 / least
        costs[name] = StepCost(
            least, BUSY_UNCERTAINTY if loaded else max(spread, BETWEEN_CALIBRATIONS), loaded
        )
    return costs


def cached(scheme: Scheme) -> StepCost | None:
    """The `StepCost` of ``scheme`` (a `rbstudy.schemes.Scheme`) cached for this machine, or
    None."""
    return _figure(_scheme_key(scheme))


def _figure(key: str) -> StepCost | None:
    """The `StepCost` cached for this machine under ``key``, or None."""
    figure: Any = _read().get(key)
    try:  # a cache edited by hand, or by another version: measured again
        cost = StepCost(float(figure["seconds"]), float(figure["uncertainty"]), figure.get("loaded") is True)
    except (TypeError, KeyError, ValueError, AttributeError):
        return None
    return cost if 0 < cost.seconds < math.inf and 0 <= cost.uncertainty < math.inf else None


# The keys this process has measured: a figure measured under load is measured again by the
# next process that calibrates, not by this one (the forecast and the sweep cost alike).
_measured_here: set[str] = set()


def _stale(key: str, cost: StepCost | None) -> bool:
    """Whether the figure ``cost`` cached under ``key`` is to be measured (again) now."""
    return cost is None or (cost.loaded and key not in _measured_here)


def _stored(cost: StepCost, seconds: float) -> dict[str, Any]:
    """What the cache file keeps of a `StepCost` measured in ``seconds``."""
    return {
        "seconds": cost.seconds,
        "uncertainty": cost.uncertainty,
        "loaded": cost.loaded,
        "measured_in_s": round(seconds, 3),
    }


def _run_seconds(scheme: Scheme, rows: tuple[np.ndarray, ...], n_steps: int) -> tuple[float, int]:
    """(CPU seconds, body-steps taken) of one run of ``n_steps`` steps of ``rows`` (state0,
    params, options)."""
    state0, params, options = rows
    out = run_batch(
        scheme, state0, params, options, CALIBRATION_DT, n_steps, min(SAMPLE_EVERY, n_steps), threads=1
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

    def timed_run(scheme):
        def run():
            clock = time.perf_counter()
            result = _run_seconds(scheme, *prepared[scheme.name])
            took[scheme.name] += time.perf_counter() - clock
            return result

        return run

    costs = _rates_in_rounds(
        {scheme.name: timed_run(scheme) for scheme in schemes if scheme.name in prepared}
    )
    return {name: (cost, took[name]) for name, cost in costs.items()}


def calibrate(names: Iterable[str], progress: Progress | None = None) -> dict[str, StepCost | None]:
    """The `StepCost` of each fixed-step scheme of ``names``: cached, else measured now and
    cached (said on ``progress``, a `rbstudy.pipeline.progress.Progress`); name -> `StepCost`."""
    # an adaptive scheme's (dop853's) cost per step taken depends on how densely it samples:
    # at the calibration's output, every 8 steps of 1e-4 s, ~4x a study's; its declared figure
    costs = {name: cached(get_scheme(name)) for name in sorted(names) if not get_scheme(name).adaptive}
    missing = [
        get_scheme(name) for name, cost in costs.items() if _stale(_scheme_key(get_scheme(name)), cost)
    ]
    if not missing:
        _say_busy(costs, progress)
        return costs
    if progress is not None:
        progress.phase(f"calibrating the cost of a step of {len(missing)} schemes (once per machine)")
    measured = measure(missing)
    _measured_here.update(_scheme_key(scheme) for scheme in missing)
    _say_busy(costs | {name: cost for name, (cost, _) in measured.items()}, progress)
    _write(
        {
            _scheme_key(scheme): _stored(*measured[scheme.name])
            for scheme in missing
            if scheme.name in measured
        }
    )
    return costs | {name: cost for name, (cost, _) in measured.items()}


def _say_busy(costs: Mapping[str, StepCost | None], progress: Progress | None) -> None:
    """Say on ``progress``, once a process, which of ``costs`` were measured while the machine
    was busy (the step search and the sweep of one command both calibrate)."""
    busy = sorted(name for name, cost in costs.items() if cost is not None and cost.loaded)
    if progress is None or not set(busy) - _said_busy:
        return
    _said_busy.update(busy)
    said = (
        f"other programs kept this machine busy while the costs of {', '.join(busy)} were "
        f"measured: they are uncertain to {BUSY_UNCERTAINTY:.0%}, and the next sweep "
        "measures them again"
    )
    progress.say(textwrap.fill(said, width=100, subsequent_indent="  ", break_on_hyphens=False))


# The schemes whose busy costs this process has said (`_say_busy`).
_said_busy: set[str] = set()


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
    cached_cost = _figure(key)
    if cached_cost is not None and not _stale(key, cached_cost):
        return cached_cost
    if not scheme.is_cached():  # compiling it here would cost the forecast seconds
        return cached_cost or StepCost(scheme.step_seconds, math.nan)
    clock = time.perf_counter()
    scene = abaqus_top_scene({"moment_space": list(REFERENCE_MOMENT)})
    y0, p = scene.state_row(), scene.param_row()
    steps = FIRST_STEPS
    while _reference_seconds(y0, p, steps)[0] < MIN_SECONDS and steps < MAX_STEPS:
        steps *= 2
    cost = _rates_in_rounds({key: lambda: _reference_seconds(y0, p, steps)})[key]
    _measured_here.add(key)
    _write({key: _stored(cost, time.perf_counter() - clock)})
    return cost
