"""Execution: a study's batches -> dask tasks -> part files -> the consolidated dataset.

One dask task per batch runs the compiled driver on all its cases and returns their outputs
(small: decimated samples only, computed through the variables table); a second task writes
them as the batch's part file. The references (closed form or DOP853) are tasks of their own,
one per chunk of distinct scenes, shared by every batch that needs them. The default
scheduler is dask's local threaded one (the kernels release the GIL); ``scheduler`` connects
to a running ``dask.distributed`` cluster and ``workers`` starts a `LocalCluster` (workers
must see the results folder).

A study folder is locked while a sweep writes it; a rerun skips the batches whose part is intact,
so a killed sweep resumes where it stopped.
"""

import contextlib
import fcntl
import logging
import os
import pathlib
import shutil
import sys
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import dask
import dask.threaded
import numpy as np

from rbstudy.errors import RbstudyError
from rbstudy.numerics.driver import clear_halt, default_threads, request_halt
from rbstudy.physics.references import reference_solutions
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.estimate import check_disk, disk_needed
from rbstudy.pipeline.integrity import SIDECAR_SUFFIX, sealed
from rbstudy.pipeline.outputs import BatchData
from rbstudy.pipeline.store import (
    Layout,
    archive_state,
    consolidate,
    global_attrs,
    open_results,
    part_complete,
    refresh_description,
    resolved_config,
    utc_now,
    write_part,
    write_text_atomic,
)
from rbstudy.pipeline.variables import evaluate
from rbstudy.schemes import get_scheme

__all__ = ["run_study", "StudyRun", "compute_batch", "compute_references", "Progress"]

# Seconds between two redraws of the progress bar.
_REDRAW_SECONDS = 0.2
# How long to wait for a --scheduler to answer: a cluster on a busy login node may be slow.
CONNECT_TIMEOUT = "10s"


@dataclass(frozen=True)
class BatchJob:
    """Everything a worker needs to run one batch (no study object: tasks stay small)."""

    scheme: str
    dt: float
    output_interval: float
    scenes: tuple
    options: tuple
    variables: tuple
    accuracy_bound: float  # rad for the orientation, relative for energy and |L|
    references: tuple  # per case: (chunk, position) in the reference chunks it is given


@dataclass(frozen=True)
class StudyRun:
    """What a sweep did: the dataset path, batches computed and reused, wall time (s),
    whether the archive was already current (nothing to do), the parts found damaged (and
    recomputed) and what was wrong with a damaged archive (rebuilt)."""

    path: pathlib.Path
    computed: int
    reused: int
    cases: int
    wall_seconds: float
    up_to_date: bool = False
    damaged_parts: int = 0
    archive_problems: tuple = ()


def compute_references(scenes, n_times, output_interval):
    """The references of ``scenes`` on the output grid of ``n_times`` samples (a dask task)."""
    return reference_solutions(scenes, np.arange(n_times) * output_interval)


def compute_batch(job, reference_chunks, threads):
    """Run one batch and return its outputs, name -> array with the case axis first.

    ``reference_chunks`` are the results of the reference tasks the batch needs; each case
    finds its own at ``job.references`` (chunk, position). ``run_time`` per case is the CPU
    time of the compiled batch call (summed over its threads) divided among the cases:
    core-seconds per case, comparable whatever the scheduler and however busy the process.
    """
    references = [reference_chunks[chunk][position] for chunk, position in job.references]
    run = simulate(job.scenes, job.scheme, job.dt, job.output_interval, list(job.options),
                   threads=threads)
    per_case = run.output.kernel_cpu_seconds / len(job.scenes)
    return evaluate(job.variables, BatchData(job.scenes, run, references,
                                             [per_case] * len(job.scenes), job.accuracy_bound))


def compile_schemes(variants):
    """Compile the schemes of ``variants``, pairs (name, timed), one after the other, before
    any batch runs: a compiling thread holds the GIL for long stretches, and a batch beside
    it would stall (run on every worker of a cluster too). ``timed`` asks for the variant
    that takes the time (loads tabulated in time, `rbstudy.numerics.clock`)."""
    for name, timed in sorted(variants):
        get_scheme(name).ensure_compiled(timed=timed)


def store_part(values, layout, batch, path):
    """Write one batch's part file atomically, its digest beside it (a dask task); returns
    the digest."""
    return write_part(layout, batch, values, path)


class Progress:
    """Cases done / total, elapsed and remaining time, redrawn in place on a terminal."""

    def __init__(self, total, label, enabled, stream=sys.stderr):
        self.total, self.label, self.enabled, self.stream = total, label, enabled, stream
        self.done = 0
        self.start = time.perf_counter()
        self._drawn = 0.0

    def advance(self, cases):
        self.done += cases
        now = time.perf_counter()
        if self.enabled and (now - self._drawn > _REDRAW_SECONDS or self.done == self.total):
            self._drawn = now
            elapsed = now - self.start
            remaining = elapsed / self.done * (self.total - self.done) if self.done else 0.0
            width = 30
            filled = int(width * self.done / max(self.total, 1))
            self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (width - filled)}] "
                              f"{self.done}/{self.total} cases, elapsed {elapsed:5.1f} s, "
                              f"remaining {remaining:5.1f} s")
            if self.done == self.total:
                self.stream.write("\n")
            self.stream.flush()


def progress_wanted(quiet):
    """A bar only on a terminal, never in CI or with --quiet."""
    return not quiet and sys.stderr.isatty() and not os.environ.get("CI")


@contextlib.contextmanager
def study_lock(folder):
    """Hold ``folder/.lock`` for the sweep; a second sweep of the same study refuses clearly.

    The lock is an advisory ``flock``: the system releases it when the process dies, so a
    killed sweep never leaves a stale lock.
    """
    path = folder / ".lock"
    handle = open(path, "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "unknown"
        handle.close()
        raise RbstudyError(f"{folder}: another rbstudy sweep is writing this study (pid "
                           f"{holder}); wait for it to finish or use another --out") from None
    try:
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        yield
    finally:
        handle.close()


def _prepare(root, study):
    folder = pathlib.Path(root) / study.name
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise RbstudyError(f"{folder}: cannot write results there ({error.strerror}); choose "
                           "another folder with --out") from None
    return folder


def _reference_chunks(study, pending):
    """The distinct scenes of the ``pending`` batches in chunks of at most a batch's size, and
    where each case's scene sits: case number -> (chunk, position).

    Chunks follow the batches' order, so a study of distinct scenes gets one chunk per batch
    and dask (which runs depth first) holds few references at a time; a study of few scenes
    gets one chunk that every batch shares.
    """
    cases = study.cases
    size = max(len(batch.cases) for batch in study.batches)
    chunks, seen, where = [], {}, {}
    for batch in pending:
        for number in batch.cases:
            row = int(cases.scene_rows[number])
            if row not in seen:
                if not chunks or len(chunks[-1]) == size:
                    chunks.append([])
                seen[row] = (len(chunks) - 1, len(chunks[-1]))
                chunks[-1].append(cases.scenes.scene(row))
            where[number] = seen[row]
    return chunks, where


def _graph(study, pending, parts_dir, threads, token):
    """Delayed store tasks of the ``pending`` batches, and one reference task per chunk of
    distinct scenes (references do not depend on the scheme or dt, so batches share them).

    Arguments are wrapped as opaque leaves (``traverse=False``): dask would otherwise walk
    every scene and number of every job looking for collections.
    """
    layout = dask.delayed(Layout.of(study), traverse=False)
    chunks, where = _reference_chunks(study, pending)
    reference_tasks = [
        dask.delayed(compute_references)(dask.delayed(tuple(scenes), traverse=False),
                                         study.n_times, study.output_interval,
                                         dask_key_name=f"references-{token}-{k}")
        for k, scenes in enumerate(chunks)]
    runs = study.cases.runs
    tasks = []
    for batch in pending:
        needed = sorted({where[i][0] for i in batch.cases})
        local = {chunk: k for k, chunk in enumerate(needed)}
        positions = tuple((local[where[i][0]], where[i][1]) for i in batch.cases)
        job = BatchJob(batch.scheme, batch.dt, study.output_interval,
                       tuple(chunks[where[i][0]][where[i][1]] for i in batch.cases),
                       tuple(runs[study.cases.run_rows[i]].options for i in batch.cases),
                       study.variables, study.accuracy_bound, positions)
        values = dask.delayed(compute_batch)(dask.delayed(job, traverse=False),
                                             [reference_tasks[k] for k in needed], threads,
                                             dask_key_name=f"batch-{token}-{batch.id}")
        tasks.append(dask.delayed(store_part)(values, layout,
                                              dask.delayed(batch, traverse=False),
                                              str(parts_dir / f"{batch.id}.nc"),
                                              dask_key_name=f"store-{token}-{batch.id}"))
    return tasks


def _run_local(tasks, sizes, progress, workers, schemes):
    """Run the tasks on this process's threads; their results, in order. On Ctrl-C (or when
    a task fails) every running kernel and reference is halted
    (`rbstudy.numerics.driver.request_halt`) and the threads are joined before the exception
    goes on: the study stays locked until nothing of this run is left working, and the
    process ends within a second."""
    from dask.callbacks import Callback

    compile_schemes(schemes)

    class _Advance(Callback):
        def _posttask(self, key, result, dsk, state, worker_id):
            if isinstance(key, str) and key.startswith("store-"):
                progress.advance(sizes[key])

    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        with _Advance():
            # the threaded scheduler itself: by its name, dask would first import
            # distributed (0.3 s) to look for a client
            return dask.compute(*tasks, scheduler=dask.threaded.get, num_workers=workers,
                                pool=pool)
    except BaseException:  # Ctrl-C, or a failed task (a full disk): stop the others too
        request_halt()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        clear_halt()  # nothing of this run works any more: later runs must not stop


def _run_distributed(tasks, sizes, progress, scheduler, workers, schemes):
    """Run the tasks on a cluster; their results, in order."""
    from distributed import Client, LocalCluster, as_completed

    with contextlib.ExitStack() as stack:
        if scheduler:
            try:
                client = stack.enter_context(Client(scheduler, timeout=CONNECT_TIMEOUT))
            except (OSError, TimeoutError) as error:
                raise RbstudyError(f"--scheduler {scheduler}: cannot connect ({error}); start "
                                   "the cluster first or drop --scheduler") from None
        else:
            cluster = stack.enter_context(LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True,
                dashboard_address=None, silence_logs=logging.ERROR))
            client = stack.enter_context(Client(cluster))
        client.run(compile_schemes, schemes)
        futures = client.compute(tasks)
        for future in as_completed(futures):
            future.result()  # a failed task raises here; finished parts stay on disk
            progress.advance(sizes[future.key])
        return [future.result() for future in futures]


def run_study(study, root, scheduler=None, workers=None, force=False, quiet=False,
              keep_parts=False):
    """Run every batch of ``study`` not already stored, then write ``<root>/<study>/<study>.nc``.

    Parameters
    ----------
    study : `rbstudy.pipeline.config.StudyConfig`.
    root : results root folder.
    scheduler : address of a running dask.distributed scheduler, or None.
    workers : start a LocalCluster of this many single-threaded worker processes, or None.
    force : recompute every batch even when its part or a current archive exists.
    quiet : no progress bar.
    keep_parts : keep ``parts/`` after the archive is written (else it is removed: the
        archive holds everything; until then the parts are what a rerun resumes from).
    """
    started_clock = time.perf_counter()
    started = utc_now()
    made = [path for path in (pathlib.Path(root), pathlib.Path(root) / study.name)
            if not path.exists()]
    folder = _prepare(root, study)
    try:
        return _run_in(folder, study, scheduler, workers, force, quiet, keep_parts, started,
                       started_clock)
    except RbstudyError:
        if made and not any(folder.glob("*.nc")) and not any(folder.glob("parts/*.nc")):
            shutil.rmtree(made[0])  # this run made the folder and left nothing worth keeping
        raise


def _run_in(folder, study, scheduler, workers, force, quiet, keep_parts, started,
            started_clock):
    """`run_study` inside its study folder."""
    parts_dir = folder / "parts"
    target = folder / f"{study.name}.nc"
    with study_lock(folder):
        for stale in [*parts_dir.glob(".*.tmp"), *folder.glob(".*.tmp")]:
            stale.unlink()  # left by a killed sweep; the lock is ours
        state, archive_problems = archive_state(target, study)
        if not force and state == "current":
            if open_results(target, ()).attrs.get("config") != study.text:
                # the same cases and code, another text (a title, a comment): redescribe
                refresh_description(target, global_attrs(study, started=started))
                write_text_atomic(resolved_config(study), folder / "study.yaml")
            return StudyRun(path=target, computed=0, reused=len(study.batches),
                            cases=len(study.cases), up_to_date=True,
                            wall_seconds=time.perf_counter() - started_clock)
        parts_dir.mkdir(exist_ok=True)
        parts = {batch.id: parts_dir / f"{batch.id}.nc" for batch in study.batches}
        digests = {} if force else {batch.id: part_complete(parts[batch.id], batch)
                                    for batch in study.batches}
        pending = [batch for batch in study.batches if digests.get(batch.id) is None]
        # a part without its digest was stopped between its rename and its digest: unfinished
        damaged = 0 if force else sum(sealed(parts[batch.id]) for batch in pending)
        check_disk(study, disk_needed(study, pending), folder)
        cores = default_threads()  # the cores this process may use (a SLURM share)
        distributed = scheduler is not None or workers is not None
        threads = 1 if distributed else max(1, cores // max(1, len(pending)))
        token = uuid.uuid4().hex[:8]  # task names unique to this run on a shared cluster
        tasks = _graph(study, pending, parts_dir, threads, token)
        sizes = {f"store-{token}-{batch.id}": len(batch.cases) for batch in pending}
        progress = Progress(sum(sizes.values()), study.name, progress_wanted(quiet))
        # the kernels take the time where the scenes have load tables (numerics/clock.py)
        timed = study.cases.scenes.loads["knots"].shape[-1] > 0
        schemes = {(batch.scheme, timed) for batch in pending}
        written = []  # the digest each store task computed of the part it wrote
        if tasks:
            if distributed:
                written = _run_distributed(tasks, sizes, progress, scheduler, workers, schemes)
            else:
                written = _run_local(tasks, sizes, progress, cores, schemes)
        # the archive is built from what the folder holds: on a cluster, workers that cannot
        # see it leave nothing there (and their digests name no part here)
        digests.update({batch.id: digest if parts[batch.id].exists() else None
                        for batch, digest in zip(pending, written, strict=True)})
        missing = [batch_id for batch_id, digest in digests.items() if digest is None]
        if missing:
            raise RbstudyError(f"{parts_dir}: {len(missing)} finished batches left no part "
                               "there; the cluster's workers must see this results folder "
                               "(give --out a shared path)")
        consolidate(study, parts, digests, target, global_attrs(study, started=started))
        write_text_atomic(resolved_config(study), folder / "study.yaml")
        if keep_parts:
            current = {path.name for path in parts.values()}
            for old in parts_dir.glob("*.nc*"):
                if old.name.removesuffix(SIDECAR_SUFFIX) not in current:
                    old.unlink()  # from an earlier version of the config
        else:
            shutil.rmtree(parts_dir)
    return StudyRun(path=target, computed=len(pending),
                    reused=len(study.batches) - len(pending), cases=len(study.cases),
                    wall_seconds=time.perf_counter() - started_clock, damaged_parts=damaged,
                    archive_problems=tuple(archive_problems))
