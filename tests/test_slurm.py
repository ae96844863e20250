"""Sweeps on a real SLURM: the single-node one `.ci/start_slurm.sh` starts (partition
`debug`). A study run in SLURM jobs gives the threaded run's archive (a zarr store written by
its workers too, with the threaded values); a worker job cancelled
mid-run, a job killed at its walltime and a job that never starts (its partition down) each
end the sweep with exit 1 and one line naming what SLURM says of the job, keep the finished
parts, and the rerun resumes to the archive of an uninterrupted run.

Skipped, with the reason, where that SLURM does not run (sinfo absent, another SLURM, the
partition down or its node busy)."""

import contextlib
import re
import shutil
import socket
import subprocess
import sys
import uuid

import pytest
import yaml
from helpers import same_numbers, write_study
from test_cluster import _parts, _slow_study, _small_study, _when_parts_appear

from rbstudy.cli import main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

PARTITION = "debug"
# dask-jobqueue's dashboard port, which another sweep or a notebook may hold.
DASHBOARD_PORT = 8787
# The cluster name .ci/start_slurm.sh gives its SLURM: the tests take a partition down, which
# they must never do to another SLURM.
CLUSTER_NAME = "rbstudy"
START = "run .ci/start_slurm.sh as root to start a single-node SLURM"
# Seconds of --worker-wait for a job that never starts: it is told this long after.
PENDING_WAIT = 5
# Seconds of --worker-wait where the job ends: longer than these tests last, since a job that
# has ended ends the sweep at once (and a job sleeping before its workers start, as below,
# has no worker meanwhile).
ENDED_WAIT = 150
# SLURM counts walltimes in whole minutes and looks for jobs past theirs every 30 s: a job of
# 1 minute is ended 60-90 s after it starts (75 s measured). Its prologue sleeps through most
# of that minute, so that its one worker has about 10-40 s for a study of about 50 s (on an
# idle core; longer on a busy one), whose batches take 1-3 s.
WALLTIME_SLEEP = 48


def _slurm_missing():
    """Why the tests cannot run here, or None."""
    if shutil.which("sinfo") is None:
        return f"no SLURM here (sinfo not found): {START}"
    config = subprocess.run(
        ["scontrol", "show", "config"], capture_output=True, text=True, timeout=30, check=False
    ).stdout
    name = re.search(r"^ClusterName\s*=\s*(\S+)", config, re.MULTILINE)
    if name is None or name.group(1) != CLUSTER_NAME:
        return (
            f"the SLURM here is not the local one ({name and name.group(1)!r} is not "
            f"{CLUSTER_NAME!r}), whose partition the tests take down: {START}"
        )
    answer = subprocess.run(
        ["sinfo", "--noheader", f"--partition={PARTITION}", "--format=partition %a, node %T"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    found = answer.stdout.strip()
    if answer.returncode or found not in ("partition up, node idle", "partition up, node mixed"):
        return (
            f"SLURM partition {PARTITION} is not up with an idle node "
            f"({found or answer.stderr.strip() or 'no node'}): {START}"
        )
    return None


pytest.importorskip("dask_jobqueue")
_MISSING = _slurm_missing()
pytestmark = pytest.mark.skipif(_MISSING is not None, reason=str(_MISSING))


def _cluster_file(folder, **options):
    """A cluster file of one SLURM job of two single-threaded workers, under a job name of
    its own (so that a test cancels its jobs only)."""
    name = f"rbstudy-test-{uuid.uuid4().hex[:8]}"
    path = folder / "slurm.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "kind": "slurm",
                "jobs": 1,
                "options": {
                    "cores": 2,
                    "processes": 2,
                    "memory": "2GB",
                    "queue": PARTITION,
                    "walltime": "00:10:00",
                    "job_name": name,
                    **options,
                },
            }
        )
    )
    return path, name


def _sweep(config, out, cluster, capsys, worker_wait=ENDED_WAIT, more=()):
    """Exit code and stderr of ``rbstudy sweep`` on ``cluster`` (with the options ``more``)."""
    code = main(
        [
            "sweep",
            str(config),
            "--out",
            str(out),
            "--quiet",
            "--cluster",
            str(cluster),
            "--worker-wait",
            str(worker_wait),
            *more,
        ]
    )
    return code, capsys.readouterr().err.strip()


@pytest.fixture(scope="module")
def slow(tmp_path_factory):
    """The slow study's config and its uninterrupted threaded archive (which also compiles
    its schemes into the cache the SLURM workers read)."""
    folder = tmp_path_factory.mktemp("slow")
    config = _slow_study(folder)
    return config, run_study(load_study(config), folder / "whole", quiet=True).path


def _resumes(config, out, uninterrupted, kept):
    """The threaded rerun reuses the ``kept`` parts, computes the rest, and gives the
    uninterrupted archive."""
    study = load_study(config)
    resumed = run_study(study, out, quiet=True)
    assert (resumed.computed, resumed.reused) == (len(study.batches) - len(kept), len(kept))
    same_numbers(uninterrupted, resumed.path)


@pytest.mark.slow
@pytest.mark.filterwarnings("error")
def test_a_study_in_slurm_jobs_gives_the_threaded_archive(tmp_path, capsys, monkeypatch):
    """... with no warning, though the dashboard's usual port is taken, and nothing written
    where it was started: the job's output (SLURM's slurm-<id>.out by default) goes among
    the parts, removed with them."""
    config = _small_study(tmp_path)
    cluster, _ = _cluster_file(tmp_path)
    started = tmp_path / "started_here"
    started.mkdir()
    monkeypatch.chdir(started)
    with socket.socket() as taken:
        with contextlib.suppress(OSError):  # taken already: as good
            taken.bind(("", DASHBOARD_PORT))
            taken.listen()
        assert _sweep(config, tmp_path / "out", cluster, capsys) == (0, "")
    threaded = run_study(load_study(config), tmp_path / "threaded", quiet=True)
    same_numbers(threaded.path, tmp_path / "out" / "small" / "small.nc")
    assert not list(started.iterdir())
    assert not (tmp_path / "out" / "small" / "parts").exists()


@pytest.mark.slow
def test_a_zarr_study_in_slurm_jobs_is_written_by_its_workers_with_the_threaded_values(tmp_path, capsys):
    """``--format zarr`` on SLURM: the job's workers write their batches into the store
    (``--writer workers``: none sends its values back; no part file, which --keep-parts would
    keep; their marks gone with the sealed store), and the store holds the threaded netCDF
    archive's values."""
    config = _small_study(tmp_path)
    cluster, _ = _cluster_file(tmp_path)
    out = tmp_path / "out"
    more = ("--format", "zarr", "--keep-parts", "--writer", "workers")
    assert _sweep(config, out, cluster, capsys, more=more) == (0, "")
    study = load_study(config)
    assert not _parts(out / "small") and not list((out / "small" / "parts").glob("*.region"))
    threaded = run_study(study, tmp_path / "threaded", quiet=True)
    same_numbers(threaded.path, out / "small" / "small.zarr")
    assert main(["verify", str(out / "small" / "small.zarr")]) == 0


@pytest.mark.slow
def test_a_cancelled_worker_job_is_named_and_the_rerun_resumes(tmp_path, capsys, slow):
    config, uninterrupted = slow
    cluster, name = _cluster_file(tmp_path)
    out = tmp_path / "out"
    cancel = _when_parts_appear(
        out / "slow", lambda: subprocess.run(["scancel", f"--name={name}"], check=True)
    )
    code, error = _sweep(config, out, cluster, capsys)
    cancel.join()
    assert code == 1 and "\n" not in error, error
    assert "every worker left" in error and "and every job ended (SLURM: job " in error, error
    assert " CANCELLED); " in error and error.endswith("rerun the same command to resume")
    kept = _parts(out / "slow")
    assert 1 <= len(kept) < 8
    # the job's output is kept with the parts, for a look at what its workers said
    assert list((out / "slow" / "parts" / "jobs").glob(f"{name}-*.err"))
    _resumes(config, out, uninterrupted, kept)


@pytest.mark.slow
def test_a_walltime_shorter_than_the_study_is_named(tmp_path, capsys):
    """A job of one minute, which sleeps through most of it (`WALLTIME_SLEEP`); the
    uninterrupted run is computed meanwhile, in a process of its own."""
    config = write_study(
        tmp_path,
        name="long",
        scene={
            "body": {"mass": 1.0, "inertia": [1.0, 1.0, 2.0]},
            "initial": {"angular_velocity": {"body": [0.25, 0.0, 6.283185307179586]}},
            "duration": 720.0,
        },
        output={"interval": 0.5},
        sweep={
            "scheme": ["rk4", "midpoint", "splitting", "leapfrog"],
            "dt": [1e-4, 1.25e-4, 1.5625e-4, 1.6e-4, 2e-4, 2.5e-4, 3.125e-4, 4e-4],
            "inertia_ratio": [0.5, 0.8, 1.5, 2.0],
        },
    )
    whole = subprocess.Popen(
        [sys.executable, "-m", "rbstudy", "sweep", str(config), "--out", str(tmp_path / "whole"), "--quiet"],
        stdout=subprocess.DEVNULL,
    )
    cluster, _ = _cluster_file(
        tmp_path, cores=1, processes=1, walltime="00:01:00", job_script_prologue=[f"sleep {WALLTIME_SLEEP}"]
    )
    out = tmp_path / "out"
    code, error = _sweep(config, out, cluster, capsys)
    assert code == 1 and "\n" not in error, error
    assert "every worker left" in error and "and every job ended (SLURM: job " in error, error
    assert " TIMEOUT (walltime 1:00)); " in error and error.endswith(
        "with a longer walltime in the cluster file"
    )
    kept = _parts(out / "long")
    assert 1 <= len(kept) < 32
    assert whole.wait() == 0
    _resumes(config, out, tmp_path / "whole" / "long" / "long.nc", kept)


@pytest.mark.slow
def test_a_job_that_never_starts_says_why_and_the_rerun_runs_on_slurm(tmp_path, capsys, slow):
    """The partition is down: the job stays pending, the sweep says so after --worker-wait,
    and cancels it; once the partition is up the same command runs the study."""
    config, uninterrupted = slow
    cluster, name = _cluster_file(tmp_path)
    out = tmp_path / "out"
    subprocess.run(["scontrol", "update", f"PartitionName={PARTITION}", "State=DOWN"], check=True)
    try:
        code, error = _sweep(config, out, cluster, capsys, PENDING_WAIT)
    finally:
        subprocess.run(["scontrol", "update", f"PartitionName={PARTITION}", "State=UP"], check=True)
    assert code == 1 and "\n" not in error, error
    assert f"for {PENDING_WAIT} s (SLURM: job " in error, error
    assert "no worker joined" in error and " PENDING (PartitionDown)); " in error, error
    assert "0 of 8 batches are kept" in error and "wait longer with --worker-wait" in error
    left = subprocess.run(
        ["squeue", "--noheader", f"--name={name}"], capture_output=True, text=True, check=True
    )
    assert not left.stdout.strip()  # the pending job was cancelled with the sweep
    assert _sweep(config, out, cluster, capsys) == (0, "")
    same_numbers(uninterrupted, out / "slow" / "slow.nc")
