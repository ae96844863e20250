"""Execution: a study's batches -> dask tasks -> part files -> the consolidated dataset.

One dask task per batch runs the compiled driver on all its cases and returns their outputs
(small: decimated samples only, computed through the variables table); a second task writes
them as the batch's part file. The references (closed form or DOP853) are tasks of their own,
one per chunk of distinct scenes, shared by every batch that needs them. The default
scheduler is dask's local threaded one (the kernels release the GIL); ``scheduler``,
``workers`` and ``cluster`` run the tasks on a ``dask.distributed`` cluster
(`rbstudy.pipeline.cluster`), whose workers write the parts where they see the results
folder and send their values back to be written here where they do not.

A study folder is locked while a sweep writes it; a rerun skips the batches whose part is intact,
so a killed sweep resumes where it stopped.
"""

from __future__ import annotations

import contextlib
import functools
import os
import pathlib
import time
import uuid
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import dask
import dask.threaded
import numpy as np

from rbstudy.archive.files import UnwritableFolder
from rbstudy.archive.folder import StudyFolder
from rbstudy.archive.lock import StudyBusy
from rbstudy.archive.parts import sees_folder
from rbstudy.archive.provenance import utc_now
from rbstudy.errors import RbstudyError, counted
from rbstudy.numerics.driver import clear_halt, request_halt
from rbstudy.numerics.machine import default_threads
from rbstudy.physics.loads import needs_time
from rbstudy.physics.reference_data import References
from rbstudy.physics.references import table_references
from rbstudy.physics.scenes import SceneTable
from rbstudy.physics.simulate import simulate
from rbstudy.physics.time_grid import output_times
from rbstudy.pipeline.batch_data import BatchData
from rbstudy.pipeline.calibration import calibrate, compile_seconds, record_compile, step_cost
from rbstudy.pipeline.cluster import LOCAL, Where, connect, dashboard_line, run_on_cluster, scheduler_lock
from rbstudy.pipeline.config import StudyConfig, resolved_config
from rbstudy.pipeline.estimate import check_disk, disk_needed
from rbstudy.pipeline.formulas import evaluate
from rbstudy.pipeline.progress import Progress
from rbstudy.schemes import get_ready, get_scheme

if TYPE_CHECKING:  # the types alone
    from dask.delayed import Delayed

    from rbstudy.archive.parts import PartTarget
    from rbstudy.archive.writer import ArchiveWriter
    from rbstudy.archive.zarr_regions import RegionTarget
    from rbstudy.pipeline.batches import Batch
    from rbstudy.schemes._ready import Compiling

__all__ = ["run_study", "study_progress", "StudyRun", "compute_batch", "compute_references"]

# How often the bar shows the archive's parts written while the last of them are copied.
_REDRAW_SECONDS = 0.2


@dataclass(frozen=True)
class BatchJob:
    """Everything a worker needs to run one batch (no study object: tasks stay small)."""

    scheme: str
    dt: float
    output_interval: float
    scene_rows: np.ndarray  # (n,) rows of the study's scene table, read by the task
    options: np.ndarray  # (n, N_OPTION) each case's scheme options, packed (Scheme.option_row)
    variables: tuple[str, ...]
    accuracy_bound: float  # rad for the orientation, relative for energy and |L|
    references: np.ndarray  # (n, 2) per case: (chunk, position) in the chunks it is given
    step_cost: tuple[float, float] = (np.nan, np.nan)  # calibrated (s, relative uncertainty) of a body-step


@dataclass(frozen=True)
class StudyRun:
    """What a sweep did: the dataset path, batches computed and reused, wall time (s),
    whether the archive was already current (nothing to do), the parts found damaged (and
    recomputed), what was wrong with a damaged archive (rebuilt), how many parts this
    process wrote from values a cluster's workers sent back (they did not see the folder),
    and how many parts left beside a current archive it removed."""

    path: pathlib.Path
    computed: int
    reused: int
    cases: int
    wall_seconds: float
    up_to_date: bool = False
    damaged_parts: int = 0
    archive_problems: tuple[str, ...] = ()
    returned: int = 0
    removed_parts: int = 0

    @property
    def said(self) -> str:
        """What the run did, in the words of its progress's end line."""
        return (
            "up to date"
            if self.up_to_date
            else f"{counted(self.computed, 'batch', 'batches')} run, {self.reused} reused"
        )


def study_progress(study: StudyConfig, quiet: bool = False) -> Progress:
    """The `rbstudy.pipeline.progress.Progress` of a sweep of ``study`` (its start line
    counts the cases and batches), to enter and hand to `run_study`."""
    return Progress(
        study.name,
        f"{counted(len(study.cases), 'case')} in {counted(len(study.batches), 'batch', 'batches')}",
        quiet=quiet,
    )


def compute_references(
    table: SceneTable, rows: np.ndarray, n_times: int, output_interval: float
) -> References:
    """The references of the scenes ``rows`` of ``table`` on the output grid of ``n_times``
    samples (a dask task)."""
    return table_references(table, rows, output_times(n_times, output_interval))


def compute_batch(
    job: BatchJob, table: SceneTable, reference_chunks: list[References], threads: int
) -> dict[str, np.ndarray]:
    """Run one batch and return its outputs, name -> array with the case axis first.

    ``reference_chunks`` are the results of the reference tasks the batch needs; each case
    finds its own at ``job.references`` (chunk, position). ``run_time`` per case is the CPU
    time of the compiled batch call (summed over its threads) divided among the cases:
    core-seconds per case, comparable whatever the scheduler and however busy the process.
    Everything is taken as columns: no object is built per case.
    """
    references = References.gather(reference_chunks, job.references)
    rows = table.batch_rows(job.scene_rows)
    run = simulate(rows, job.scheme, job.dt, job.output_interval, job.options, threads=threads)
    per_case = run.output.kernel_cpu_seconds / len(job.scene_rows)
    return evaluate(
        job.variables,
        BatchData(table, job.scene_rows, run, references, per_case, job.accuracy_bound, job.step_cost),
    )


class Delivered(NamedTuple):
    """What a store task returns: the ``digest`` of the part its worker wrote, or the
    ``values`` for this process to write (the other None)."""

    digest: str | None
    values: dict[str, np.ndarray] | None


def deliver_part(
    values: dict[str, np.ndarray],
    target: PartTarget | RegionTarget,
    writer: str,
    probe: tuple[str, str] | None,
) -> Delivered:
    """Write one batch's part file atomically, its digest beside it (or its region of a zarr
    store, and its mark), at its ``target`` (`rbstudy.archive.parts.PartTarget`,
    `rbstudy.archive.zarr_regions.RegionTarget`) and return its digest; or return the
    ``values`` for the client to write it (a dask task).

    The worker writes when ``writer`` is "workers", or "auto" and it sees the results folder:
    it reads ``probe`` (path, token), the file this run left there (None: the client's own
    process, which sees it).
    """
    if writer == "client" or (writer == "auto" and not sees_folder(probe)):
        return Delivered(digest=None, values=values)
    if not sees_folder(probe):
        raise RbstudyError(
            f"{pathlib.Path(target.path).parent}: a worker on {os.uname().nodename} "
            "does not see this results folder; use --writer auto or client "
            "(the workers send the values back)"
        )
    return Delivered(digest=target.write(values), values=None)


def _show_compiling(progress: Progress, name: str, compiling: Compiling) -> None:
    """`rbstudy.schemes.get_ready`'s watch: a first run said before anything is compiled, on
    any stream, then shown as it goes, with the time left by what each scheme took to compile
    the last time (`_compile_left`); the seconds they took now kept for the next."""
    total, done, running = compiling.total, compiling.done, compiling.running
    left = _compile_left(compiling, compile_seconds())
    wait = "" if left is None else f"~{left:.0f} s left, "  # first: the bar cuts long words
    if not done and not running:
        progress.say(
            f"{name}: compiling {counted(total, 'scheme')} first, {compiling.processes} "
            "at a time, once per machine\n  and rbstudy version, into numba's cache "
            f"{compiling.cache}"
        )
        # no rate: the schemes take very different times and end in bunches, so the rate so
        # far forecast many times the wait; the count done, and what they took the last time
        progress.phase(f"{name}: {wait}compiling {counted(total, 'scheme')}", total, "schemes", eta=False)
    elif done < total:
        words = f"{wait}compiling {', '.join(running)}" if running else "loading the compiled schemes"
        progress.update(f"{name}: {words}", done)
    else:
        record_compile(dict(compiling.took))
        progress.update(f"{name}: loading the compiled schemes", done)


def _compile_left(compiling: Compiling, figures: Mapping[str, float]) -> float | None:
    """Seconds left of a `rbstudy.schemes._ready.Compiling` by ``figures`` (name -> the seconds
    each took the last time; a scheme without one is taken at their mean): the schemes not
    done shared by its processes, or the longest of them, which no process shares. None
    without a figure or the schemes' names."""
    if not figures or not compiling.names:
        return None
    finished = {name for name, _ in compiling.took}
    remaining = [
        figures.get(name, sum(figures.values()) / len(figures))
        for name in compiling.names
        if name not in finished
    ]
    if not remaining:
        return 0.0
    return max(sum(remaining) / compiling.processes, max(remaining))


def _reference_chunks(study: StudyConfig, pending: Sequence[Batch]) -> tuple[list[np.ndarray], np.ndarray]:
    """The distinct scenes (rows of the scene table) of the ``pending`` batches in chunks of
    at most a batch's size, and where each case's scene sits: (n, 2) (chunk, position), a
    row per case of the pending batches in their order.

    Chunks follow the batches' order (a scene's place is that of its first case), so a
    study of distinct scenes gets one chunk per batch and dask (which runs depth first)
    holds few references at a time; a study of few scenes gets one chunk that every batch
    shares. Arrays, not Python objects: a million cases' places took 200 MiB as tuples.
    """
    if not pending:
        return [], np.empty((0, 2), dtype=np.int64)
    size = max(len(batch.cases) for batch in study.batches)
    rows = study.cases.scene_rows[np.concatenate([batch.cases for batch in pending])]
    distinct, first = np.unique(rows, return_index=True)
    by_first_use = np.argsort(first, kind="stable")
    rank = np.empty(len(distinct), dtype=np.int64)
    rank[by_first_use] = np.arange(len(distinct))
    ranks = rank[np.searchsorted(distinct, rows)]
    chunks = [distinct[by_first_use[start : start + size]] for start in range(0, len(distinct), size)]
    return chunks, np.stack([ranks // size, ranks % size], axis=1)


def _graph(
    folder: StudyFolder,
    pending: Sequence[Batch],
    share: _Share,
    writer: str,
    probe: tuple[str, str] | None,
) -> tuple[list[Delayed], dict[str, PartTarget | RegionTarget]]:
    """Delayed store tasks of the ``pending`` batches of ``folder``'s study, and one reference
    task per chunk of distinct scenes (references do not depend on the scheme or dt, so
    batches share them); and the targets of the store tasks, key -> `PartTarget`. ``writer``
    and ``probe``: as `deliver_part` takes them.

    Arguments are wrapped as opaque leaves (``traverse=False``): dask would otherwise walk
    every number of every job looking for collections. The scene table is one shared
    argument (one copy per worker of a cluster), from which each task builds the scenes of
    its rows: the scenes of 1e5 cases built up front took 270 MiB, and long to build.
    """
    study, token = folder.study, share.token
    table = dask.delayed(study.cases.scenes, traverse=False)
    chunks, where = _reference_chunks(study, pending)
    reference_tasks = [
        dask.delayed(compute_references)(
            table,
            dask.delayed(rows, traverse=False),
            study.n_times,
            study.output_interval,
            dask_key_name=f"references-{token}-{k:06d}",
        )
        for k, rows in enumerate(chunks)
    ]
    # each distinct run's options packed once: a million cases' dicts were slow to pack
    option_rows = np.array([get_scheme(run.scheme).option_row(run.options) for run in study.cases.runs])
    tasks, targets = [], {}
    start = 0
    # keys numbered down: dask's order breaks its ties by key, the highest first (2026.8), so
    # the batches run in the study's order, the one in which the archive written beside them
    # takes their parts (by the ids alone, the first batch could run last)
    for number, batch in zip(range(len(pending) - 1, -1, -1), pending, strict=True):
        places = where[start : start + len(batch.cases)]
        start += len(batch.cases)
        needed = np.unique(places[:, 0])
        positions = np.stack([np.searchsorted(needed, places[:, 0]), places[:, 1]], axis=1)
        numbers = np.asarray(batch.cases)
        job = BatchJob(
            scheme=batch.scheme,
            dt=batch.dt,
            output_interval=study.output_interval,
            scene_rows=study.cases.scene_rows[numbers],
            options=option_rows[study.cases.run_rows[numbers]],
            variables=study.variables,
            accuracy_bound=study.accuracy_bound,
            references=positions,
            step_cost=_step_cost(study, batch),
        )
        key = f"store-{token}-{number:06d}-{batch.id}"  # the task that writes its part
        values = dask.delayed(compute_batch)(
            dask.delayed(job, traverse=False),
            table,
            [reference_tasks[k] for k in needed],
            share.threads,
            dask_key_name=_computing_key(key),
        )
        target = folder.part(batch)
        tasks.append(
            dask.delayed(deliver_part)(
                values,
                dask.delayed(target, traverse=False),
                writer,
                probe,
                dask_key_name=key,
            )
        )
        targets[key] = target
    return tasks, targets


def _computing_key(store_key: str) -> str:
    """The key of the task that computes the batch whose part the task ``store_key`` writes."""
    return "batch" + store_key.removeprefix("store")


def _step_cost(study: StudyConfig, batch: Batch) -> tuple[float, float]:
    """The calibrated (s, relative uncertainty) of a body-step of ``batch``: a batch never
    mixes costs (`plan_batches`), so its first case's run stands for all."""
    run = study.cases.runs[study.cases.run_rows[batch.cases[0]]]
    cost = step_cost(get_scheme(batch.scheme), run.options)
    return cost.seconds, cost.uncertainty


def _run_local(
    tasks: list[Delayed],
    targets: dict[str, PartTarget | RegionTarget],
    progress: Progress,
    workers: int,
    writer: ArchiveWriter,
) -> dict[str, str]:
    """Run the tasks on this process's threads; {key: digest} of the parts they wrote, each
    handed to the archive's ``writer`` (`rbstudy.archive.writer.ArchiveWriter`) as soon as
    it is written. On Ctrl-C (or when a task fails) every running kernel and reference is halted
    (`rbstudy.numerics.driver.request_halt`) and the threads are joined before the exception
    goes on: the study stays locked until nothing of this run is left working, and the
    process ends within a second."""
    from dask.callbacks import Callback

    computing = {_computing_key(key): target.batch for key, target in targets.items()}

    class _Advance(Callback):
        def _posttask(self, key, result, dsk, state, worker_id):
            if key in computing:  # the values, which the archive takes without reading the part
                writer.computed(computing[key], result)
            elif key in targets:
                progress.advance(targets[key].cases)
                writer.arrived(targets[key].batch.id, result.digest)

    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        with _Advance():
            # the threaded scheduler itself: by its name, dask would first import
            # distributed, which is slow to import, to look for a client
            written = dask.compute(*tasks, scheduler=dask.threaded.get, num_workers=workers, pool=pool)
        return {key: delivered.digest for key, delivered in zip(targets, written, strict=True)}
    except BaseException:  # Ctrl-C, or a failed task (a full disk): stop the others too
        request_halt()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        clear_halt()  # nothing of this run works any more: later runs must not stop


def run_study(
    study: StudyConfig,
    root: str | os.PathLike,
    *,
    where: Where = LOCAL,
    force: bool = False,
    quiet: bool = False,
    keep_parts: bool = False,
    progress: Progress | None = None,
) -> StudyRun:
    """Run every batch of ``study`` not already stored, then write ``<root>/<study>/<study>.nc``.

    Parameters
    ----------
    study : the study.
    root : results root folder.
    where : this process's threads (the default) or a cluster, and who writes the parts there
        (`rbstudy.pipeline.cluster.Where`).
    force : recompute every batch even when its part or a current archive exists.
    quiet : no progress (`rbstudy.pipeline.progress`: a bar on a terminal, else a start
        and an end line).
    keep_parts : keep ``parts/`` after the archive is written (else it is removed: the
        archive holds everything; until then the parts are what a rerun resumes from).
    progress : a `rbstudy.pipeline.progress.Progress` under way to show the run in (the
        conformance's golden studies share one), else the study's own.
    """
    started_clock = time.perf_counter()
    started = utc_now()
    folder = StudyFolder.of(root, study, unit_lock=scheduler_lock if where.distributed else None)
    folder.make()
    with contextlib.ExitStack() as stack:
        own = progress is None
        shown = stack.enter_context(study_progress(study, quiet)) if progress is None else progress
        sweep = _Sweep(
            folder=folder,
            where=where,
            force=force,
            progress=shown,
            keep_parts=keep_parts,
            started=started,
            started_clock=started_clock,
        )
        run = _run_in(sweep)
        if own:
            shown.end = run.said
    return run


@dataclass(frozen=True)
class _Sweep:
    """A sweep under way, as `run_study` was asked for it: its `StudyFolder` (made), where its
    tasks run, whether it recomputes every batch, the `Progress` that shows it, whether it
    keeps the parts, and when it started (UTC, which the archive records, and the
    performance counter, for its wall time)."""

    folder: StudyFolder
    where: Where
    force: bool
    progress: Progress
    keep_parts: bool
    started: str
    started_clock: float


@dataclass(frozen=True)
class _Share:
    """How a sweep shares out its batches: the cores this process may use, the kernel
    threads each batch gets, and the token that names its tasks (unique to the run on a
    shared cluster)."""

    cores: int
    threads: int
    token: str


def _run_in(sweep: _Sweep) -> StudyRun:
    """`run_study` as the `_Sweep` ``sweep`` says."""
    folder, force, progress = sweep.folder, sweep.force, sweep.progress
    study = folder.study
    try:
        lock = folder.lock()
    except StudyBusy:
        raise  # the other sweep's folder: nothing of it is removed
    except RbstudyError as error:
        # A read-only folder can still answer a rerun of its study: every file in it is
        # replaced whole by a rename, so reading needs no lock. Only when there is nothing
        # to write: the archive current and intact, and described by this very text.
        if isinstance(error, UnwritableFolder) and not force and folder.answers_unchanged():
            return _up_to_date(sweep)
        folder.remove_made()  # a full disk refused the lock's pid
        raise
    with lock, folder.refusals():
        # again under the lock, before anything is written or deleted: the command line
        # checks every study before it runs any, but another sweep may claim the folder since
        folder.check_claim(force)
        folder.claim()
        folder.clear_stale()  # left by a killed sweep; the lock is ours
        state = folder.state()
        if not force and state.current:
            folder.redescribe(sweep.started, resolved_config(study))
            removed = 0 if sweep.keep_parts else folder.remove_parts()
            return _up_to_date(sweep, removed)
        folder.make_parts()
        digests = {} if force else _checked_parts(folder, progress)
        pending = [batch for batch in study.batches if digests.get(batch.id) is None]
        damaged = 0 if force else folder.damaged(pending)
        check_disk(study, disk_needed(study, pending), folder.path)
        cores = default_threads()  # the cores this process may use (a SLURM share)
        share = _Share(
            cores=cores,
            threads=1 if sweep.where.distributed else max(1, cores // max(1, len(pending))),
            token=uuid.uuid4().hex[:8],
        )
        # the kernels take the time where the scenes have load tables, or loads only those
        # kernels carry (numerics/clock.py)
        timed = needs_time(study.cases.scenes.loads)
        # Before any batch, whatever runs them: a compiling thread holds the GIL for long
        # stretches, and a batch beside it would stall; a cluster's workers then load from
        # the cache what this process put there (a worker whose processor differs compiles
        # at its first batch), and a first run is announced here, not in a worker's log.
        get_ready(
            [(get_scheme(name), timed) for name in {batch.scheme for batch in pending}],
            cores,
            watch=functools.partial(_show_compiling, progress, study.name),
        )
        # then each scheme's cost per step, which the parts store (once per machine: cached)
        calibrate({batch.scheme for batch in pending}, progress)
        # the archive is written by a thread of its own as the parts arrive, in the batches'
        # order: its compression, on one core, runs beside the batches
        with folder.writer(digests, sweep.started) as writer:
            returned = _run_tasks(sweep, pending, share, writer)
            progress.phase(f"{study.name}: writing the archive", len(study.batches), "parts")
            while not writer.wait(_REDRAW_SECONDS):
                progress.update(done=writer.copied)
        folder.write_config(resolved_config(study))
        folder.finish_parts(sweep.keep_parts)
    return StudyRun(
        path=folder.archive,
        computed=len(pending),
        reused=len(study.batches) - len(pending),
        cases=len(study.cases),
        wall_seconds=time.perf_counter() - sweep.started_clock,
        damaged_parts=damaged,
        archive_problems=state.problems,
        returned=returned,
    )


def _checked_parts(folder: StudyFolder, progress: Progress) -> dict[str, str | None]:
    """The digest of each of the study's batches whose part is on disk and intact (None:
    damaged); only parts on disk are checked, and said to be: an empty folder has none."""
    study = folder.study
    stored = folder.stored(study.batches)
    if stored:
        progress.phase(f"{study.name}: checking stored parts", len(stored), "parts")
    digests = {}
    for batch, digest in folder.checked(stored):
        digests[batch.id] = digest
        progress.advance()
    return digests


def _run_tasks(sweep: _Sweep, pending: Sequence[Batch], share: _Share, writer: ArchiveWriter) -> int:
    """Run the ``pending`` batches here or on the cluster the sweep's ``where`` names, each
    part handed to the archive's ``writer`` once written; the number of parts the workers
    returned to be written here."""
    folder, where, progress = sweep.folder, sweep.where, sweep.progress
    study = folder.study
    distributed = where.distributed and bool(pending)
    with folder.probe(share.token) if distributed else contextlib.nullcontext() as probe:
        tasks, targets = _graph(folder, pending, share, where.writer, probe)
        written: dict[str, str] = {}  # the digest of each part, by its store task's key
        returned = 0
        cases = sum(target.cases for target in targets.values())
        if distributed:
            progress.phase(f"{study.name}: {where.starting}")
            with connect(where.scheduler, where.workers, where.cluster, logs=folder.job_logs) as client:
                progress.say(f"{study.name}: {dashboard_line(client)}")
                progress.phase(f"{study.name}: running batches", cases, "cases")
                written, returned = run_on_cluster(
                    client,
                    tasks,
                    targets,
                    progress,
                    where.worker_wait,
                    fixed_jobs=where.cluster is not None and where.cluster.jobs is not None,
                )
        elif tasks:
            progress.phase(f"{study.name}: running batches", cases, "cases")
            written = _run_local(tasks, targets, progress, share.cores, writer)
    for key, target in targets.items():
        writer.arrived(target.batch.id, written[key])
    return returned


def _up_to_date(sweep: _Sweep, removed_parts: int = 0) -> StudyRun:
    """The `StudyRun` of a sweep that found its archive current: nothing run (but
    ``removed_parts`` left beside it)."""
    folder, started_clock = sweep.folder, sweep.started_clock
    return StudyRun(
        path=folder.archive,
        computed=0,
        reused=len(folder.study.batches),
        cases=len(folder.study.cases),
        up_to_date=True,
        wall_seconds=time.perf_counter() - started_clock,
        removed_parts=removed_parts,
    )
