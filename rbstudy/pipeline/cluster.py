"""Running a study's tasks on a dask.distributed cluster, and telling its failures in one line.

Three ways to a cluster (`connect`): ``--scheduler ADDRESS`` joins a running one,
``--workers N`` starts a `LocalCluster` of N single-threaded processes, and ``--cluster FILE``
builds one from a cluster file (`read_cluster_file`): a `LocalCluster`, or batch jobs of
SLURM or PBS through dask-jobqueue (the optional extra ``rbstudy[cluster]``).

Who writes a batch's part file (``--writer``): a worker that sees the study's results folder
writes it there; a worker that does not (another machine, another working directory) sends
the values back and this process writes the part, with the same bytes and digest. ``auto``
decides per task, by whether the worker can read the probe file this run left in the
folder; ``workers`` and ``client`` force one way.

The failures users of batch clusters meet end the run with one line, keeping every part
written so far (a rerun resumes from them): a worker killed at its walltime or memory limit
more often than the scheduler allows (``KilledWorker``); no worker joining, or every worker
gone, for `worker_wait` seconds; the scheduler going away. On a SLURM cluster it started, the
line says what squeue says of the jobs (pending and why, past their walltime, cancelled), and
a fixed number of jobs that have all ended ends the run at once.
"""

from __future__ import annotations

import contextlib
import importlib.util
import inspect
import logging
import math
import os
import pathlib
import signal
import socket
import time
from collections.abc import Iterator
from concurrent.futures import CancelledError
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

from rbstudy.archive.parts import PartTarget, sealed
from rbstudy.errors import ConfigError, RbstudyError, counted, did_you_mean, one_line
from rbstudy.inputs.reader import Reader
from rbstudy.inputs.yaml_file import read_yaml_file
from rbstudy.pipeline.batch_jobs import UNASKED, jobs_said
from rbstudy.pipeline.progress import Progress

if TYPE_CHECKING:  # the types alone: distributed is imported where a cluster is used
    from dask.delayed import Delayed
    from distributed import Client, Future, Lock, Worker

    from rbstudy.archive.zarr_regions import RegionTarget

__all__ = [
    "ClusterFile",
    "Where",
    "LOCAL",
    "read_cluster_file",
    "check_scheduler",
    "connect",
    "run_on_cluster",
    "scheduler_lock",
    "dashboard_line",
    "WRITERS",
    "WORKER_WAIT",
    "CONNECT_TIMEOUT",
]

WRITERS = ("auto", "workers", "client")
# Seconds to wait for a first worker (batch jobs queue) or for workers to come back.
WORKER_WAIT = 600.0
# How long to wait for a --scheduler to answer: a cluster on a busy login node may be slow.
CONNECT_SECONDS = 10.0
CONNECT_TIMEOUT = f"{CONNECT_SECONDS:g}s"
# Seconds between two looks at the cluster's workers, and between two looks for finished
# batches when none has finished.
POLL_SECONDS = 1.0
_IDLE_SECONDS = 0.02
# Seconds to fetch a finished batch's values from its worker; past it, the worker is taken
# for dead (distributed then runs the batch again) and the batch is awaited anew.
GATHER_SECONDS = 60.0
# The dask-jobqueue class of each batch system a cluster file may name.
JOB_CLUSTERS = {"slurm": "SLURMCluster", "pbs": "PBSCluster"}
_KEYS = ("kind", "jobs", "adaptive", "options")
# Seconds between two questions to the batch system while a cluster of fixed jobs has no
# worker: each is a call to the controller, which a busy cluster's admins ask not to be made
# often.
JOBS_LOOK_SECONDS = 5.0
# How to get dask's dashboard, which bokeh draws (distributed's optional dependency).
DASHBOARD_FIX = "pip install 'rbstudy[dashboard]'"
# The module of a study's tasks, which the forkserver of local workers imports.
TASKS_MODULE = "rbstudy.pipeline.execute"


@dataclass(frozen=True)
class ClusterFile:
    """A cluster to start for a sweep: ``kind`` (local, slurm, pbs), a fixed number of
    ``jobs`` (worker processes for local) or ``adaptive`` bounds (minimum, maximum), and
    the keyword ``options`` of its dask class, passed on as written."""

    path: str
    kind: str
    jobs: int | None
    adaptive: tuple[int, int] | None
    options: dict[str, Any]


@dataclass(frozen=True)
class Where:
    """Where a sweep (`rbstudy.pipeline.execute.run_study`) runs its tasks: this process's
    threads (the default), or a cluster, reached as `connect` says.

    scheduler : address of a running dask.distributed scheduler. workers : start a
    `LocalCluster` of this many single-threaded worker processes. cluster : start the cluster
    of a `ClusterFile`. writer : on a cluster, who writes the part files (`WRITERS`):
    "workers", "client" (this process, from the values the workers send back) or "auto" (the
    workers where they see the results folder). worker_wait : seconds a cluster may have no
    worker before the run ends (jobs queue).
    """

    scheduler: str | None = None
    workers: int | None = None
    cluster: ClusterFile | None = None
    writer: str = "auto"
    worker_wait: float = WORKER_WAIT

    @property
    def distributed(self) -> bool:
        return (self.scheduler, self.workers, self.cluster) != (None, None, None)

    @property
    def starting(self) -> str:
        """What a run does while it reaches its cluster."""
        return (
            f"connecting to {self.scheduler}"
            if self.scheduler
            else f"starting {counted(self.workers, 'worker')}"
            if self.workers
            else "starting the cluster"
        )


# The tasks on this process's threads: no cluster.
LOCAL = Where()


def read_cluster_file(path: str | os.PathLike[str]) -> ClusterFile:
    """The `ClusterFile` at ``path``, or a one-line `ConfigError` naming the key and the fix."""
    path = str(path)
    _, data = read_yaml_file(path)
    reader = Reader(path, ConfigError)
    data = reader.mapping(data, "", _KEYS)
    kinds = ("local", *JOB_CLUSTERS)
    kind = data.get("kind")
    if kind not in kinds:
        reader.fail("kind", f"expected one of {', '.join(kinds)}, got {kind!r}")
    if ("jobs" in data) == ("adaptive" in data):
        reader.fail(
            "jobs", "give either jobs (a fixed number) or adaptive (minimum and maximum), not both or neither"
        )
    jobs = reader.count(data["jobs"], "jobs") if "jobs" in data else None
    adaptive = None
    if "adaptive" in data:
        bounds = reader.mapping(data["adaptive"], "adaptive", ("minimum", "maximum"))
        if set(bounds) != {"minimum", "maximum"}:
            reader.fail("adaptive", "give minimum and maximum")
        minimum = reader.count(bounds["minimum"], "adaptive.minimum", minimum=0)
        adaptive = (minimum, reader.count(bounds["maximum"], "adaptive.maximum"))
        if adaptive[1] < minimum:
            reader.fail("adaptive.maximum", f"{adaptive[1]} is below the minimum {minimum}")
    options = data.get("options") or {}
    if not isinstance(options, dict) or not all(isinstance(key, str) for key in options):
        reader.fail("options", f"expected a mapping of keyword arguments, got {options!r:.80}")
    _check_options(reader, kind, options)
    return ClusterFile(path, kind, jobs, adaptive, options)


def _keywords(*classes: Any) -> set[str]:
    """The names of the keyword arguments the ``__init__`` of ``classes`` take."""
    return {
        name
        for cls in classes
        for name, parameter in inspect.signature(cls.__init__).parameters.items()
        if parameter.kind in (parameter.POSITIONAL_OR_KEYWORD, parameter.KEYWORD_ONLY)
    } - {"self"}


def _check_options(reader: Reader, kind: str, options: dict[str, Any]) -> None:
    """Refuse, before a sweep prints anything, the ``options`` of a cluster of ``kind`` that
    no class they reach takes (a local cluster passes those it does not take to each worker:
    Nanny, Worker, Server; a job cluster to each job), and a local cluster's counts of
    workers and threads that are none: distributed would say so only once the cluster
    starts, after the forecast. A job cluster without dask-jobqueue is left to `_start`,
    which says how to install it."""
    if kind == "local":
        from distributed import LocalCluster, Nanny, Worker
        from distributed.core import Server

        named, taken = "LocalCluster", _keywords(LocalCluster, Nanny, Worker, Server)
        for name, least in (("n_workers", 0), ("threads_per_worker", 1)):
            if options.get(name) is not None:
                reader.count(options[name], f"options.{name}", minimum=least)
    else:
        try:
            import dask_jobqueue
            from dask_jobqueue.core import Job, JobQueueCluster
        except ImportError:
            return
        named = JOB_CLUSTERS[kind]
        cluster = getattr(dask_jobqueue, named)
        taken = _keywords(cluster, JobQueueCluster, cluster.job_cls, Job)
    for name in options:
        if name not in taken:
            reader.fail(
                f"options.{name}",
                f"no keyword argument of {named} or its workers{did_you_mean(name, taken)}",
                f"see the keyword arguments of {named}",
            )
    _check_memory(reader, kind, options)


# The option that gives each worker's (local) or job's memory; "auto": the machine's share.
_MEMORY_OPTIONS = {"local": ("memory_limit", ("auto",)), "slurm": ("memory", ()), "pbs": ("memory", ())}


def _check_memory(reader: Reader, kind: str, options: dict[str, Any]) -> None:
    """Refuse a memory option that is no amount (``memory_limit: lots``) before the forecast:
    distributed would say so only as the cluster starts."""
    from dask.utils import parse_bytes

    name, words = _MEMORY_OPTIONS[kind]
    value = options.get(name)
    if not isinstance(value, str) or value in words:
        return
    try:
        parse_bytes(value)
    except ValueError:
        reader.fail(
            f"options.{name}",
            f"{value!r} is no amount of memory",
            'give bytes with units, e.g. "4GB"' + "".join(f", or {word}" for word in words),
        )


def check_scheduler(address: str) -> None:
    """Refuse ``address`` (--scheduler) in one line, before a sweep prints anything, when it
    is no scheduler address (``tcp://host:port``) or nothing listens there: a TCP connection
    tried for at most `CONNECT_SECONDS` (the protocols other than tcp and tls are left to
    `connect`)."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address)
        if protocol not in ("tcp", "tls"):
            return
        host, port = parse_host_port(location)
    except ValueError as error:
        raise RbstudyError(
            f"--scheduler {address}: not a scheduler address ({one_line(error)}); give tcp://host:port"
        ) from None
    try:
        socket.create_connection((host, port), timeout=CONNECT_SECONDS).close()
    except OSError as error:
        raise RbstudyError(
            f"--scheduler {address}: cannot connect ({error.strerror or one_line(error) or 'timed out'}); "
            "start the cluster first or drop --scheduler"
        ) from None


def start_forkserver() -> str:
    """Start the process from which a local cluster's workers are forked, importing
    distributed and rbstudy's task module (`TASKS_MODULE`) once, where the system has one
    (Linux, macOS), and return the start method of local workers: "forkserver", else
    "spawn". Running it again only returns the method. Called as early as a command knows
    it will start a local cluster, so that those imports overlap its own work."""
    import multiprocessing
    from multiprocessing import forkserver

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return "spawn"
    forkserver.set_forkserver_preload(["distributed", TASKS_MODULE])
    forkserver.ensure_running()
    return "forkserver"


def _forked_local_cluster(**options: Any) -> Any:
    """A `LocalCluster` whose workers are forked from the forkserver (`start_forkserver`),
    which holds distributed and rbstudy imported, rather than spawned: a spawned worker
    starts Python and imports both itself. A forkserver is one thread with no file of the
    sweep open, unlike the sweep process, which a plain fork would copy with its scheduler's
    threads and its study lock."""
    import warnings

    import dask
    from distributed import LocalCluster

    with (
        dask.config.set({"distributed.worker.multiprocessing-method": start_forkserver()}),
        warnings.catch_warnings(),
    ):
        # another dask (a second sweep, a notebook) holding the dashboard's port 8787 is no
        # fault: distributed takes another port, and `dashboard_line` says which
        warnings.filterwarnings("ignore", "Port .* is already in use", UserWarning)
        return LocalCluster(**options)


def dask_setup(worker: Worker) -> None:
    """Run by each local worker process as it starts (dask's preload hook): it ignores
    Ctrl-C. A Ctrl-C at the terminal reaches the sweep's whole process group, its workers
    too, which printed their tracebacks (4, 63 lines for two workers); the sweep process,
    interrupted, ends them itself as it closes the cluster."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _bokeh() -> bool:
    """Whether bokeh, which draws dask's dashboard, is installed."""
    return importlib.util.find_spec("bokeh") is not None


def dashboard_line(client: Client) -> str:
    """Where the dask dashboard of ``client``'s scheduler is, or why there is none and how to
    get one, in one line. Without bokeh here there is none: the scheduler serves its
    dashboard's address all the same, with nothing on its pages (a remote scheduler with
    bokeh of its own is taken for one without)."""
    if not _bokeh():
        return f"no dask dashboard: it needs bokeh; {DASHBOARD_FIX}"
    with contextlib.suppress(Exception):  # a scheduler gone: the run will say so
        if "dashboard" in client.scheduler_info(n_workers=0).get("services", {}):
            return f"dask dashboard at {client.dashboard_link}"
    return "no dask dashboard: the scheduler runs none"


def _start(spec: ClusterFile, logs: str | os.PathLike[str] | None = None) -> Any:
    """The cluster ``spec`` describes, started and scaled (not yet connected); a job
    cluster's jobs write their output into ``logs`` unless the cluster file or dask's
    configuration names a ``log_directory``."""
    if spec.kind == "local":
        make, name = _forked_local_cluster, "LocalCluster"
        options = {
            "n_workers": spec.jobs or 0,
            "threads_per_worker": 1,
            "processes": True,
            # on a free port, where bokeh can draw it
            "dashboard_address": ":0" if _bokeh() else None,
            "silence_logs": logging.CRITICAL,
            "preload": [__name__],
            **spec.options,
        }  # its dask_setup, in each worker
    else:
        try:
            import dask_jobqueue
        except ImportError:
            raise ConfigError(
                f"a {spec.kind} cluster needs dask-jobqueue",
                "pip install 'rbstudy[cluster]'",
                spec.path,
                "kind",
            ) from None
        import dask

        name = JOB_CLUSTERS[spec.kind]
        make = getattr(dask_jobqueue, name)
        options = spec.options
        # else SLURM and PBS write each job's output where the sweep was started
        if logs is not None and dask.config.get(f"jobqueue.{spec.kind}.log-directory", None) is None:
            options = {"log_directory": str(logs), **options}
        # the dashboard on a free port unless the file names one: dask-jobqueue's 8787, taken
        # (by another sweep, a notebook), made distributed print a warning
        scheduler = options.get(
            "scheduler_options", dask.config.get(f"jobqueue.{spec.kind}.scheduler-options", None) or {}
        )
        if isinstance(scheduler, dict):
            options = {**options, "scheduler_options": {"dashboard_address": ":0", **scheduler}}
    refused: str | None
    try:
        cluster = make(**options)
    except (TypeError, ValueError, RuntimeError) as error:
        # a worker that fails to start on a bad option says why in the cause
        cause = error.__cause__
        refused = one_line(error) + (
            f" ({type(cause).__name__}: {one_line(cause)})" if cause is not None else ""
        )
    else:
        refused = None
    if refused is not None:
        raise ConfigError(refused, f"see the keyword arguments of {name}", spec.path, "options")
    if spec.adaptive:
        minimum, maximum = spec.adaptive
        if spec.kind == "local":
            cluster.adapt(minimum=minimum, maximum=maximum)
        else:
            cluster.adapt(minimum_jobs=minimum, maximum_jobs=maximum)
    elif spec.kind != "local":
        cluster.scale(jobs=spec.jobs)
    return cluster


def scheduler_lock(name: str) -> Lock:
    """The lock ``name`` held across the cluster, by its scheduler (`distributed.Lock`): what a
    worker holds while it writes a unit of a zarr store (`rbstudy.archive.zarr_regions`), from
    the worker's or this process's connection to the scheduler. A lock whose holder stops
    renewing it (a worker killed) is freed after ``distributed.scheduler.locks.lease-timeout``
    (30 s by default)."""
    from distributed import Lock

    return Lock(name)


@contextlib.contextmanager
def connect(
    scheduler: str | None = None,
    workers: int | None = None,
    cluster: ClusterFile | None = None,
    logs: str | os.PathLike[str] | None = None,
) -> Iterator[Client]:
    """A `distributed.Client` of the running ``scheduler``, of a `LocalCluster` of
    ``workers`` processes, or of the cluster a `ClusterFile` describes, whose batch jobs
    write their output into the folder ``logs`` (unless the file names another); the
    cluster this started is closed (its jobs cancelled) on the way out.

    distributed's own log lines are held back meanwhile: a failure ends the run with one
    line of ours (`run_on_cluster`), not pages of reconnection tracebacks."""
    from distributed import Client

    # distributed's configuration gives some of its loggers levels of their own
    loggers = [
        logging.getLogger(name)
        for name in list(logging.root.manager.loggerDict)
        if name.partition(".")[0] == "distributed"
    ]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    try:
        with contextlib.ExitStack() as stack:
            if scheduler:
                try:
                    client = Client(scheduler, timeout=CONNECT_TIMEOUT)
                except (OSError, TimeoutError, ValueError) as error:  # ValueError: no port
                    raise RbstudyError(
                        f"--scheduler {scheduler}: cannot connect "
                        f"({one_line(error)}); "
                        "start the cluster first or drop --scheduler"
                    ) from None
            else:
                spec = cluster or ClusterFile("--workers", "local", workers, None, {})
                started = stack.enter_context(contextlib.closing(_start(spec, logs)))
                client = Client(started)
            # a client whose scheduler has gone would retry for its whole timeout
            stack.callback(client.close, timeout=2)
            yield client
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def run_on_cluster(
    client: Client,
    tasks: list[Delayed],
    targets: dict[str, PartTarget | RegionTarget],
    progress: Progress,
    worker_wait: float = WORKER_WAIT,
    fixed_jobs: bool = False,
) -> tuple[dict[str, str], int]:
    """Run the store ``tasks`` on ``client``'s cluster; ({key: digest}, number of parts this
    process wrote from values sent back).

    ``targets`` gives each task's key its `rbstudy.archive.parts.PartTarget`: a task returns
    (digest, None) when its worker wrote the part, (None, values) when this process must.
    Futures are released as they finish, so a worker holds no values once they are written.
    ``fixed_jobs``: the cluster's batch jobs were submitted once (a cluster file's ``jobs``),
    so when the batch system says every one has ended while no worker is there, none can
    come back and the run ends at once rather than after ``worker_wait``.
    """
    from distributed import as_completed

    futures = client.compute(tasks)
    watch = _Watch(client, targets, progress, worker_wait, fixed_jobs)
    pending = set(futures)
    finishing = as_completed(futures)  # bound to this client's loop, unlike distributed.wait
    digests = {}
    try:
        while pending:
            watch.look(time.monotonic())
            finished = finishing.next_batch(block=False)
            if not finished:
                time.sleep(_IDLE_SECONDS)
            for future in finished:
                digest = watch.take(future)
                if digest is None:  # its worker died before it was gathered: run again
                    finishing.add(future)
                    continue
                digests[future.key] = digest
                pending.discard(future)
                future.release()
    except (CancelledError, OSError) as error:  # distributed's CommClosedError is an OSError
        if client.status == "running" and not isinstance(error, CancelledError):
            raise  # this machine's own trouble (a full disk writing a part)
        raise RbstudyError(
            f"the scheduler {watch.where} went away (or cancelled this run); {watch.kept()}"
        ) from None
    finally:
        with contextlib.suppress(Exception):  # nothing to tell a scheduler that has gone
            client.cancel(list(pending))  # a shared cluster stops working for this run
    return digests, watch.returned


class _Watch:
    """What `run_on_cluster` keeps an eye on: whether the cluster has workers (one look a
    `POLL_SECONDS`), how long it has had none, what its batch system says of its jobs, and
    the batches that come back (``returned``: how many parts it wrote from values sent
    back)."""

    def __init__(
        self,
        client: Client,
        targets: dict[str, PartTarget | RegionTarget],
        progress: Progress,
        worker_wait: float,
        fixed_jobs: bool,
    ):
        self.client, self.targets, self.progress = client, targets, progress
        self.worker_wait, self.fixed_jobs = worker_wait, fixed_jobs
        self.where = client.scheduler.address
        self.waiting_since: float | None = None
        self.seen_workers = False
        self.returned = 0
        self.looked = self.asked = -math.inf
        # parts already sealed (a --force run, a damaged part) prove nothing about this run
        self.sealed_before = {target.path for target in targets.values() if sealed(target.path)}

    def kept(self) -> str:
        """What is kept for a rerun, counted on disk: a worker may have written a part whose
        news was lost."""
        paths = [target.path for target in self.targets.values()]
        return (
            f"{sum(map(sealed, paths))} of {counted(len(paths), 'batch', 'batches')} are kept in "
            f"{pathlib.Path(paths[0]).parent}: rerun the same command to resume"
        )

    def look(self, now: float) -> None:
        """A look at the workers, once a `POLL_SECONDS`: an `RbstudyError` when none has been
        there for ``worker_wait`` s, or the batch system says every fixed job has ended."""
        if now - self.looked < POLL_SECONDS:
            return
        self.looked = now
        if self.client.nthreads():
            self.waiting_since, self.seen_workers = None, True
            return
        if self.waiting_since is None:
            self.waiting_since = now
            if not self.seen_workers:
                self.progress.say(
                    f"{self.progress.label}: waiting up to {self.worker_wait:g} s for a worker "
                    f"to join {self.where}"
                )
            return
        word = None
        if self.fixed_jobs and now - self.asked >= JOBS_LOOK_SECONDS:
            self.asked, word = now, jobs_said(self.client)
        waited = now - self.waiting_since > self.worker_wait
        if waited or (word and word.ended):
            # a part this run wrote proves a worker, even one that came and went between
            # two looks
            self.seen_workers = self.seen_workers or any(
                sealed(target.path)
                for target in self.targets.values()
                if target.path not in self.sealed_before
            )
            what = "every worker left" if self.seen_workers else "no worker joined"
            when = f"for {self.worker_wait:g} s" if waited else "and every job ended"
            said, fix, _ = word or jobs_said(self.client) or UNASKED
            raise RbstudyError(f"{what} {self.where} {when} ({said}); {self.kept()}{fix}")

    def take(self, future: Future) -> str | None:
        """The digest of the part of a finished batch's ``future``, written here when its
        worker sent the values back; None when its worker died before its values were
        gathered. An `RbstudyError` when its workers died too often."""
        from distributed import KilledWorker

        key = cast(str, future.key)  # the store tasks are named by strings (execute._graph)
        try:
            digest, values = future.result(timeout=GATHER_SECONDS)
        except TimeoutError:
            return None
        except KilledWorker as error:
            allowed = error.args[2] if len(error.args) > 2 else "?"
            raise RbstudyError(
                f"batch {self.targets[key].batch.id}: its workers died while running "
                f"it, more often than {self.where} allows (KilledWorker, allowed-failures "
                f"= {allowed}: killed at their walltime or memory limit?); {self.kept()}, "
                "with a longer walltime or more memory per worker"
            ) from None
        self.seen_workers = True  # a batch that came back had a worker (see `look`)
        target = self.targets[key]
        if values is not None:
            digest = target.write(values)
            self.returned += 1
        self.progress.advance(target.cases)
        return digest
