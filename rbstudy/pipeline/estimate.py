"""What a study will cost before it runs, and the limits past which it is refused.

`estimate` forecasts, from the config alone: the body-steps of every case (`step_count`;
for the adaptive dop853, its steps per radian turned), the integrations of each reference no
closed form gives (the composed exact-flow splitting, run again where a load may spin the body
past its planned step, and DOP853; a run past its step budget is not taken, or stopped there)
and which cases would have neither within its step budget, the run time on this machine's
cores (each scheme's seconds per body-step calibrated on this machine,
`rbstudy.pipeline.calibration`, else its declared `rbstudy.schemes.Scheme.step_seconds`;
DOP853's as the references take it, `calibration.reference_cost`), the process's peak
memory (a measured baseline plus the batches in flight and the values held for the
archive's writer) and the bytes the parts and the
archive need on disk. `check_limits` refuses a study past ``--max-body-steps``,
``--max-memory`` or the free space of the results folder, with the estimate and the fix.

A loaded body's radians and fastest spin are forecast as if the load kept speeding it up all
run (`rbstudy.physics.references.load_spin`): the most it can, so a load that does not (a
moment turning with a tumbling body) makes the references' work smaller than forecast.
"""

from __future__ import annotations

import os
import pathlib
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rbstudy.errors import ConfigError, counted
from rbstudy.numerics.block import FEWEST
from rbstudy.numerics.machine import default_threads
from rbstudy.physics.analytic import INTEGRATED
from rbstudy.physics.loads import BLOCKLESS, constant_acting, needs_time
from rbstudy.physics.references import (
    COMPOSED_STEP_ANGLE,
    REFERENCE_MAX_STEPS,
    REFERENCE_OPTIONS,
    REFERENCE_SCHEME,
    REFERENCE_STEPS_PER_RADIAN,
    knot_steps,
    load_spin,
    planned_steps,
)
from rbstudy.physics.time_grid import output_count, step_count
from rbstudy.pipeline.calibration import calibrate, reference_cost, step_cost
from rbstudy.schemes import Scheme, get_scheme

if TYPE_CHECKING:  # the types alone: the config imports the sweep's every module
    from rbstudy.physics.scenes import SceneTable
    from rbstudy.pipeline.batches import Batch
    from rbstudy.pipeline.config import StudyConfig
    from rbstudy.pipeline.grid import Cases

__all__ = [
    "Estimate",
    "estimate",
    "describe",
    "duration_text",
    "check_limits",
    "check_disk",
    "disk_needed",
    "forecast_disk",
    "MAX_BODY_STEPS",
    "MEMORY_FRACTION",
    "ZARR_ADVISED_BYTES",
    "zarr_advice",
    "PROCESS_BYTES",
    "physical_memory",
]

# Default of --max-body-steps: hours of one core even for the fastest schemes; a study past it
# is far more likely a slip of dt or duration than an intent.
MAX_BODY_STEPS = 1e11
# Default of --max-memory: this share of the machine's memory.
MEMORY_FRACTION = 0.5
# Resident memory of a sweep process before any batch: Python, numpy, scipy, numba, dask and
# xarray loaded and the schemes compiled (330-420 MiB measured, docs/performance.md).
PROCESS_BYTES = 400 * 2**20
# A batch in flight holds its sampled states, its references (about as large) and the derived
# variables being built from both: about this many times its sampled states and outputs.
IN_FLIGHT_FACTOR = 3
# What a netCDF file holds besides its data (HDF5 structure, coordinates, attributes), and a
# part's digest beside it: 32-34 KiB measured for a part, rounded up.
_FILE_OVERHEAD = 40 * 2**10
_MIB = 2**20
_GIB = 2**30
# Past this many bytes of values (uncompressed, `Estimate.archive_bytes`), `validate` and
# `sweep` advise the zarr store (`zarr_advice`). The netCDF archive is one file that one
# process writes, every value through one core's zlib (docs/performance.md, "A million cases:
# the archive written beside the batches"): the largest study timed on one machine, 1e6 cases
# of 11 samples (3.1 GiB of values), spent half its core-time compressing them. Past it a
# study is one for a cluster, where a folder of shard files (zarr) that many processes open
# at once serves better than one file every value passes through.
ZARR_ADVISED_BYTES = 4 * _GIB
# Each load evaluation of a scene with tables in time bisects the study's K knots
# (`rbstudy.numerics.space_loads.knot_segment`): a step costs about this share more per level,
# log2(K). Measured on 2e5 steps of a loaded asymmetric body, leapfrog, euler and rk4 alike,
# from K = 100 to 1e5 knots against 2 (docs/performance.md).
KNOT_LEVEL_SHARE = 0.025


def _mib(size: float) -> str:
    """Bytes as MiB, with a decimal below 10 MiB."""
    return f"{size / _MIB:,.1f}" if size < 10 * _MIB else f"{size / _MIB:,.0f}"


def physical_memory() -> int:
    """This machine's memory, in bytes."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def _inside_run(knots: np.ndarray, duration: float) -> np.ndarray:
    """Which of ``knots`` (..., K) fall inside the run (0, ``duration``): those a reference
    restarts at, or puts on a step boundary."""
    knots = np.asarray(knots)
    return (knots > 0.0) & (knots < duration)


def _composed_runs(scenes: SceneTable, rows: np.ndarray, interval: float) -> tuple[np.ndarray, np.ndarray]:
    """Forecast of the composed reference of each scene ``rows`` of a `SceneTable`: (steps
    of the runs it takes, whether it is had), each (n,). Its first run is planned from the
    initial spin (at once, and the knot search only for the scenes whose load tables have knots
    inside the run); where a load may spin the body past twice the planned rate
    (`load_spin`), it runs again at a step fitted to that spin, as
    `rbstudy.physics.references` does. A run past `REFERENCE_MAX_STEPS` is not taken, and
    costs nothing; no run, or a second one not taken, leaves the scene without it."""
    loads = {name: np.asarray(column)[rows] for name, column in scenes.loads.items()}
    omega, inertia = scenes.omega_body[rows], scenes.inertia[rows]
    intervals = output_count(scenes.duration, interval) - 1
    knots = loads["knots"]
    inside = np.flatnonzero(_inside_run(knots, scenes.duration).any(axis=-1))

    # counts per interval with the knots on step boundaries, 0 where none
    def fitted(least: np.ndarray) -> np.ndarray:
        for k in inside:
            least[k] = knot_steps(knots[k], scenes.duration, interval, int(least[k])) or 0
        return least

    first = fitted(planned_steps(omega, inertia, loads, interval))
    first_runs = (first > 0) & (first * intervals <= REFERENCE_MAX_STEPS)
    fastest = np.linalg.norm(omega, axis=-1) + load_spin(inertia, loads, scenes.duration)
    angle = interval * fastest / np.maximum(first, 1)
    again = first_runs & (angle > 2.0 * COMPOSED_STEP_ANGLE)
    second = np.zeros_like(first)
    second[again] = fitted(np.ceil(first * angle / COMPOSED_STEP_ANGLE).astype(np.int64))[again]
    second_runs = again & (second > 0) & (second * intervals <= REFERENCE_MAX_STEPS)
    steps = (first * first_runs + second * second_runs) * intervals
    return steps, first_runs & (~again | second_runs)


def _dop853_steps(scenes: SceneTable) -> np.ndarray:
    """Forecast of accepted DOP853 steps at rtol 1e-13 for each scene of a
    `rbstudy.physics.scenes.SceneTable` (n,), as floats (a spin of 1e20 rad/s forecasts
    steps past any integer): steps per radian of the radians the body turns, ``|w0| T`` at its
    initial spin plus ``M T^2 / 2 I_min`` for the spin a load may add (`load_spin`), plus the
    few a slow run still takes, plus one per knot of its load tables inside the run (DOP853
    restarts at each)."""
    loaded = load_spin(scenes.inertia, scenes.loads, scenes.duration)
    turned = (np.linalg.norm(scenes.omega_body, axis=-1) + loaded / 2.0) * scenes.duration
    restarts = _inside_run(scenes.loads["knots"], scenes.duration).sum(axis=-1)
    return np.ceil(REFERENCE_STEPS_PER_RADIAN * turned) + 16 + restarts


@dataclass(frozen=True)
class Estimate:
    """A study's forecast cost.

    body_steps : steps over every case (the schemes studied). references : distinct scenes
    whose reference is integrated; reference_steps : the forecast steps of the integrations
    they take (`_composed_runs`, and DOP853's capped at the budget); over_budget : cases
    whose integrations would both pass `REFERENCE_MAX_STEPS` (they get reference "none"). scheme_seconds : the
    schemes' batches alone; core_seconds : schemes and references together;
    longest_seconds : the longest batch or reference on its own (a batch spreads over at
    most its bodies, a reference over one core), which no number of cores shortens; cores :
    this machine's. peak_bytes : the process's peak memory. archive_bytes : the archive,
    uncompressed (compression usually halves it); the disk a sweep needs is `disk_needed`.
    """

    body_steps: int
    references: int
    reference_steps: int
    over_budget: int
    scheme_seconds: float
    core_seconds: float
    longest_seconds: float
    cores: int
    peak_bytes: int
    archive_bytes: int

    @property
    def wall_seconds(self) -> float:
        """Kernel time on ``cores`` cores: the work spread over them, unless one batch or
        reference takes longer on its own (start-up, compilation and writing not included)."""
        return max(self.core_seconds / self.cores, self.longest_seconds)


def _knot_factor(scenes: SceneTable) -> float:
    """How much dearer a kernel step is for the bisection of the knots of ``scenes``' load
    tables in time (1 without; `KNOT_LEVEL_SHARE`)."""
    knots = scenes.loads["knots"].shape[-1]
    return 1.0 + KNOT_LEVEL_SHARE * float(np.log2(knots)) if knots > 1 else 1.0


def _block_shares(scenes: SceneTable) -> np.ndarray | None:
    """(scenes,) True where a scene's body can step in a block of bodies
    (`rbstudy.numerics.block_run.plain_loads`: no load of a kind the blocks do not carry), or
    None when no scene can: loads tabulated in time compile kernels of their own, without
    blocks."""
    if needs_time(scenes.loads):
        return None
    return ~np.asarray(constant_acting(scenes.loads, BLOCKLESS), dtype=bool)


def _batch_step_seconds(batch: Batch, scheme: Scheme, cases: Cases, plain: np.ndarray | None) -> float:
    """Core-seconds a body-step of ``batch`` takes: one body after another at its scheme's
    calibrated cost (`rbstudy.pipeline.calibration.step_cost`; the declared
    `rbstudy.schemes.Scheme.step_seconds` where it is not calibrated yet), and in blocks
    across SIMD lanes for the share of its bodies that can step in them, where it can fill a
    block (`_block_shares`: ``plain``), the declared block cost scaled alike."""
    rows = list(batch.cases)
    # a batch never mixes costs (`plan_batches`): its first case's options stand for all
    options = cases.runs[cases.run_rows[rows[0]]].options
    single = step_cost(scheme, options).seconds
    if plain is None or len(rows) < FEWEST:
        return single
    block = scheme.block_seconds_per_step(options)
    if block is None:
        return single
    share = float(np.mean(plain[cases.scene_rows[rows]]))
    return share * block * single / scheme.seconds_per_step(options) + (1.0 - share) * single


def estimate(study: StudyConfig, cores: int | None = None) -> Estimate:
    """The `Estimate` of ``study`` on ``cores`` cores (default: this machine's)."""
    cores = cores or default_threads()
    cases = study.cases
    knot_factor = _knot_factor(cases.scenes)
    plain = _block_shares(cases.scenes)
    dop853_steps = _dop853_steps(cases.scenes)  # per distinct scene
    # the schemes ready to run now (an engine's adapter, kernels in numba's cache) are costed
    # as measured here (once per machine); the others at their declared cost until the sweep
    # has compiled and measured them
    names = {batch.scheme for batch in study.batches}
    calibrate({name for name in names if get_scheme(name).is_cached()})
    # the scenes whose references are integrated (by DOP853, among others), one per distinct
    # scene without a closed form
    rows = np.flatnonzero(cases.scenes.reference_kinds == INTEGRATED)
    # DOP853's step as the references take it, measured here once its kernel is compiled
    peer_seconds = reference_cost().seconds if rows.size or "dop853" in names else 0.0
    body_steps, seconds, longest = 0, 0.0, 0.0
    for batch in study.batches:
        scheme = get_scheme(batch.scheme)
        if scheme.adaptive:
            steps = int(dop853_steps[cases.scene_rows[list(batch.cases)]].sum())
        else:
            steps = len(batch.cases) * step_count(study.duration, study.output_interval, batch.dt)
        body_steps += steps
        # a batch holds one cost per body-step (a composition's stages: `plan_batches`); dop853
        # steps as the references do
        dop853 = batch.scheme == "dop853"
        per_step = peer_seconds if dop853 else _batch_step_seconds(batch, scheme, cases, plain)
        batch_seconds = steps * per_step * knot_factor
        seconds += batch_seconds
        # a batch spreads its bodies over at most as many threads as it has bodies; dop853
        # is Python and holds the interpreter: one core
        spread = 1 if scheme.adaptive else min(cores, len(batch.cases))
        longest = max(longest, batch_seconds / spread)
    scheme_seconds = seconds
    peer = dop853_steps[rows]
    composed, had = _composed_runs(cases.scenes, rows, study.output_interval)
    neither = np.zeros(len(dop853_steps), dtype=bool)
    neither[rows] = (peer > REFERENCE_MAX_STEPS) & ~had
    over_budget = int(np.sum(neither[cases.scene_rows]))
    peer = np.minimum(peer, REFERENCE_MAX_STEPS)  # DOP853 stops there
    per_composed = step_cost(get_scheme(REFERENCE_SCHEME), REFERENCE_OPTIONS).seconds
    each = peer * peer_seconds + composed * per_composed
    seconds += float(each.sum())
    longest = max(longest, float(each.max(initial=0.0)))
    reference_steps = int(peer.sum() + composed.sum())
    largest = max(len(batch.cases) for batch in study.batches)
    running = min(len(study.batches), cores)
    in_flight = IN_FLIGHT_FACTOR * study.working_bytes_per_case() * largest * running
    # here: the writer's module loads netCDF4 and h5py, which the forecast needs nowhere else
    from rbstudy.archive.writer import HELD_BYTES

    # the values a local run hands the archive's writer, held until it takes them
    held = min(HELD_BYTES, study.bytes_per_case() * len(study.cases))
    return Estimate(
        body_steps=body_steps,
        references=len(rows),
        reference_steps=reference_steps,
        over_budget=over_budget,
        scheme_seconds=scheme_seconds,
        core_seconds=seconds,
        longest_seconds=longest,
        cores=cores,
        peak_bytes=PROCESS_BYTES + in_flight + held,
        archive_bytes=study.bytes_per_case() * len(study.cases),
    )


def disk_needed(study: StudyConfig, pending: Sequence[Batch]) -> int:
    """Bytes on disk for the parts of the batches ``pending`` and the archive, which coexist
    until the parts are removed (both uncompressed, with each file's overhead)."""
    cases = sum(len(batch.cases) for batch in pending)
    return (cases + len(study.cases)) * study.bytes_per_case() + (len(pending) + 1) * _FILE_OVERHEAD


def duration_text(seconds: float) -> str:
    """``~17 h`` (``~3.2e+12 h``), ``~3 min``, ``~2.5 s`` or ``under 0.1 s``."""
    for unit, size in (("h", 3600.0), ("min", 60.0)):
        if seconds >= 2 * size:  # digits past a million hours say nothing more
            count = seconds / size
            return f"~{count:,.0f} {unit}" if count < 1e6 else f"~{count:.1e} {unit}"
    if seconds < 0.1:
        return "under 0.1 s"
    return f"~{seconds:.1f} s" if seconds < 10 else f"~{seconds:,.0f} s"


def describe(study: StudyConfig, cost: Estimate) -> str:
    """One line: cases, batches, output times and the `Estimate`."""
    axes = " x ".join(f"{d.name} {d.size}" for d in study.dimensions) or "one case"
    text = (
        f"{study.name}: {counted(len(study.cases), 'case')} ({axes}) in "
        f"{counted(len(study.batches), 'batch', 'batches')}, {study.n_times} output times; "
        f"{cost.body_steps:.2g} body-steps"
    )
    if cost.references:
        text += (
            f" and {cost.reference_steps:.2g} reference steps "
            f"({counted(cost.references, 'scene')}, each integrated twice)"
        )
    text += (
        f", kernels {duration_text(cost.wall_seconds)} on {counted(cost.cores, 'core')}; archive "
        f"~{cost.archive_bytes / _MIB:,.1f} MiB, peak memory ~{cost.peak_bytes / _MIB:,.0f} MiB"
    )
    if cost.over_budget:
        text += (
            f"; no reference within {REFERENCE_MAX_STEPS:.0e} steps for "
            f"{counted(cost.over_budget, 'case')} (too many turns): reference = none there"
        )
    return text


def zarr_advice(study: StudyConfig, cost: Estimate, advised_bytes: float = ZARR_ADVISED_BYTES) -> str | None:
    """The line advising the zarr store for ``study`` (its `Estimate` ``cost``), or None: only
    for a netCDF archive of more than ``advised_bytes`` of values."""
    if study.output_format != "netcdf" or cost.archive_bytes <= advised_bytes:
        return None
    return (
        f"{study.path}: advice: over {advised_bytes / _GIB:.3g} GiB of values: "
        "output.format: zarr in the config, or sweep --format zarr"
    )


def _free_bytes(folder: str | os.PathLike[str]) -> int:
    """Free bytes on the file system that holds ``folder`` (or would: its nearest existing
    ancestor)."""
    path = pathlib.Path(folder).absolute()
    while not path.exists():
        path = path.parent
    return shutil.disk_usage(path).free


def check_limits(
    study: StudyConfig,
    cost: Estimate,
    max_body_steps: float = MAX_BODY_STEPS,
    max_memory: float | None = None,
) -> None:
    """Refuse ``study`` (a `ConfigError` naming the file and the limit) when its `Estimate`
    ``cost`` passes ``max_body_steps`` or ``max_memory`` (bytes; default half this machine's
    memory). The disk is checked against what is left to write (`check_disk`)."""
    if cost.body_steps > max_body_steps:
        raise ConfigError(
            f"needs {cost.body_steps:.2g} body-steps, kernels {duration_text(cost.wall_seconds)} on "
            f"{counted(cost.cores, 'core')} (limit {max_body_steps:.2g}, --max-body-steps)",
            "use a larger dt, a shorter duration or fewer cases, or raise --max-body-steps",
            source=study.path,
            key="sweep" if study.dimensions else "run.dt",
        )
    limit = max_memory if max_memory is not None else MEMORY_FRACTION * physical_memory()
    if cost.peak_bytes > limit:
        which = "--max-memory" if max_memory is not None else "half of this machine's"
        raise ConfigError(
            f"needs about {cost.peak_bytes / _MIB:,.0f} MiB of memory at once (limit "
            f"{limit / _MIB:,.0f} MiB, {which})",
            "sweep fewer values, a shorter duration or a longer output.interval",
            source=study.path,
            key="sweep" if study.dimensions else "output.interval",
        )


def check_disk(study: StudyConfig, needed: int, folder: str | os.PathLike[str]) -> None:
    """Refuse ``study`` when ``needed`` bytes exceed the free space where ``folder`` is (or
    would be)."""
    free = _free_bytes(folder)
    if needed > free:
        raise ConfigError(
            f"needs up to {_mib(needed)} MiB on disk for its parts and archive; "
            f"{_mib(free)} MiB are free under {folder}",
            "free space, give --out another disk, or store fewer variables "
            "(output.variables) or samples (output.interval)",
            source=study.path,
            key="output",
        )


def forecast_disk(study: StudyConfig, out: str | os.PathLike[str]) -> int:
    """`disk_needed` for a sweep into the results root ``out``: the batches whose part is
    not there yet, and the archive."""
    # here: the folder's module loads netCDF4 and h5py, which the forecast needs nowhere else
    from rbstudy.archive.folder import StudyFolder

    folder = StudyFolder.of(out, study)
    return disk_needed(study, [batch for batch in study.batches if not folder.part_path(batch.id).exists()])
