"""What a batch system says of the jobs of a cluster rbstudy started, for the line that ends a
run whose cluster has no worker (`rbstudy.pipeline.cluster.run_on_cluster`).

SLURM is asked (squeue); another batch system, or a cluster rbstudy did not start, is not,
and the line then asks the user to look (`UNASKED`).
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["JobsWord", "UNASKED", "jobs_said", "JOB_QUERY_SECONDS"]

# Seconds to wait for the batch system to describe a cluster's jobs: a slow controller must
# not hold back the run's last line for long.
JOB_QUERY_SECONDS = 10
# Job ids named per state in that line (an adaptive cluster may have hundreds of jobs).
_JOBS_NAMED = 3
# The SLURM states of a job that has ended for good (a preempted or requeued job may run
# again; a completing one may still be requeued).
_SLURM_ENDED = frozenset(
    {"BOOT_FAIL", "CANCELLED", "COMPLETED", "DEADLINE", "FAILED", "NODE_FAIL", "OUT_OF_MEMORY", "TIMEOUT"}
)


class JobsWord(NamedTuple):
    """What a batch system says of a cluster's jobs: the words for the line, the fix that
    follows its count of the parts kept, and whether every job has ended for good."""

    said: str
    fix: str
    ended: bool


# What the worker-wait line says when the batch system was not asked (a --scheduler or a local
# cluster, PBS) or did not answer.
UNASKED = JobsWord(
    "are the workers' jobs queued or ended? squeue, qstat", ", or wait longer with --worker-wait", False
)


def _slurm_jobs(ids: Sequence[str]) -> JobsWord | None:
    """SLURM's word on the jobs ``ids`` (squeue, every state: a finished job is known for
    the controller's MinJobAge, 300 s by default), a `JobsWord`, or None when squeue does
    not answer.

    Jobs alike are named together: ``SLURM: job 7 PENDING (PartitionDown)``, ``SLURM: job 8
    TIMEOUT (walltime 1:00)``, ``SLURM: job 9 CANCELLED``."""
    answer = subprocess.run(
        ["squeue", "--noheader", "--states=all", f"--jobs={','.join(ids)}", "--format=%i %T %r %l"],
        capture_output=True,
        text=True,
        timeout=JOB_QUERY_SECONDS,
        check=False,
    )
    rows = [line.split() for line in answer.stdout.splitlines()]
    if answer.returncode or not rows or any(len(row) != 4 for row in rows):
        return None
    alike: dict[tuple[str, str], list[str]] = {}
    timed_out = False
    for job, state, reason, limit in rows:
        # a pending job's reason is why it waits; an ended job keeps its last one (a job
        # cancelled while pending still says Resources), so only a passed walltime is told
        # (TIMEOUT, or TimeLimit while its processes are being ended)
        passed = state == "TIMEOUT" or reason == "TimeLimit"
        timed_out |= passed
        why = reason if state == "PENDING" else f"walltime {limit}" if passed else ""
        alike.setdefault((state, why), []).append(job)
    said = []
    for (state, why), jobs in alike.items():
        named = ", ".join(jobs[:_JOBS_NAMED]) + (", ..." if len(jobs) > _JOBS_NAMED else "")
        said.append(f"job{'s' * (len(jobs) > 1)} {named} {state}" + (f" ({why})" if why else ""))
    fix = (
        ", with a longer walltime in the cluster file"
        if timed_out
        else ", or wait longer with --worker-wait"
        if any(state == "PENDING" for state, _ in alike)
        else ""
    )
    return JobsWord("SLURM: " + ", ".join(said), fix, all(state in _SLURM_ENDED for state, _ in alike))


# How to ask each batch system about its jobs, by dask-jobqueue class.
_ASK_JOBS: dict[str, Callable[[Sequence[str]], JobsWord | None]] = {"SLURMCluster": _slurm_jobs}


def jobs_said(client: Client) -> JobsWord | None:
    """What the batch system says of the jobs of ``client``'s cluster (a `JobsWord`), or None
    when rbstudy did not start that cluster, cannot ask its batch system, or got no answer."""
    cluster = getattr(client, "cluster", None)
    ask = _ASK_JOBS.get(type(cluster).__name__)
    ids = [job.job_id for job in getattr(cluster, "workers", {}).values() if getattr(job, "job_id", None)]
    if ask is None or not ids:
        return None
    try:
        return ask(ids)
    except (OSError, subprocess.SubprocessError):  # squeue missing here, or too slow
        return None
