"""Sweeps on a dask.distributed cluster: workers that do not see the results folder send
their values back, and the failures of batch clusters (a killed worker, no workers, a
scheduler gone) end the run in one line, keep the finished parts, and a rerun resumes."""

import os
import pathlib
import re
import signal
import subprocess
import sys
import threading
import time

import dask
import pytest
import yaml
from distributed import Client, LocalCluster
from helpers import abaqus_mapping, same_numbers, write_study

from rbstudy.cli import main
from rbstudy.errors import ConfigError, RbstudyError
from rbstudy.pipeline.cluster import Where, read_cluster_file
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study


def _small_study(folder):
    return write_study(
        folder,
        name="small",
        sweep={"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005], "inertia_ratio": [0.5, 2.0]},
    )


def _slow_study(folder):
    """Eight batches of about a second of kernels each (two worker processes)."""
    return write_study(
        folder,
        name="slow",
        scene={
            "body": {"mass": 1.0, "inertia": [1.0, 1.0, 2.0]},
            "initial": {"angular_velocity": {"body": [0.25, 0.0, 6.283185307179586]}},
            "duration": 60.0,
        },
        output={"interval": 0.1},
        sweep={
            "scheme": ["rk4", "midpoint", "splitting", "leapfrog"],
            "dt": [1e-4, 2e-4],
            "inertia_ratio": [0.5, 0.8, 1.5, 2.0],
        },
    )


def _parts(folder):
    """The finished part files of a study folder (each with its digest beside it)."""
    return sorted(
        path.name
        for path in (folder / "parts").glob("*.npz")
        if path.with_name(path.name + ".sha256").exists()
    )


def _start_workers(address, count, cwd):
    """``count`` single-threaded ``dask worker`` processes without a nanny (a killed one
    stays dead, as a batch job at its walltime), working in ``cwd``."""
    return [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "distributed.cli.dask_worker",
                address,
                "--nthreads",
                "1",
                "--no-nanny",
                "--no-dashboard",
            ],
            cwd=cwd,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for _ in range(count)
    ]


def _stop(processes):
    for process in processes:
        process.kill()
        process.wait()


def _when_parts_appear(folder, action):
    """Run ``action`` in a thread as soon as ``folder`` holds a finished part."""

    def watch():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if (folder / "parts").exists() and _parts(folder):
                action()
                return
            time.sleep(0.01)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


@pytest.mark.slow
def test_workers_that_do_not_see_the_results_folder_send_their_values_back(tmp_path, monkeypatch):
    """Workers in another working directory: the relative results folder the client names
    is not theirs. auto has them send every part back; workers refuses in one line; the
    parts the client writes are the parts a threaded run writes (a rerun reuses them)."""
    config = _small_study(tmp_path)
    threaded = run_study(load_study(config), tmp_path / "threaded", quiet=True)
    client_side, elsewhere = tmp_path / "client", tmp_path / "elsewhere"
    client_side.mkdir()
    elsewhere.mkdir()
    monkeypatch.chdir(client_side)
    with LocalCluster(n_workers=0, dashboard_address=None) as cluster:
        workers = _start_workers(cluster.scheduler_address, 2, elsewhere)
        try:
            with Client(cluster) as client:
                client.wait_for_workers(2, timeout=60)
            with pytest.raises(
                RbstudyError, match="does not see this results folder; use --writer auto or client"
            ) as refused:
                run_study(
                    load_study(config),
                    "results",
                    quiet=True,
                    where=Where(scheduler=cluster.scheduler_address, writer="workers"),
                )
            assert "\n" not in str(refused.value)
            remote = run_study(
                load_study(config),
                "results",
                keep_parts=True,
                where=Where(scheduler=cluster.scheduler_address),
                quiet=True,
            )
        finally:
            _stop(workers)
    assert remote.returned == remote.computed == 4
    assert remote.path == pathlib.Path("results/small/small.nc")
    same_numbers(threaded.path, client_side / remote.path)
    assert not (elsewhere / "results").exists()  # the workers wrote nothing where they run
    remote.path.unlink()
    again = run_study(load_study(config), "results", quiet=True)
    assert (again.computed, again.reused) == (0, 4)  # same parts, same identity
    same_numbers(threaded.path, again.path)


@pytest.mark.slow
def test_client_writer_on_a_shared_folder_gives_the_same_parts(tmp_path):
    config = _small_study(tmp_path)
    threaded = run_study(load_study(config), tmp_path / "threaded", quiet=True)
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
        shared = run_study(
            load_study(config),
            tmp_path / "shared",
            where=Where(scheduler=cluster.scheduler_address),
            quiet=True,
        )
        sent = run_study(
            load_study(config),
            tmp_path / "sent",
            where=Where(scheduler=cluster.scheduler_address, writer="client"),
            quiet=True,
        )
    assert (shared.returned, sent.returned) == (0, 4)
    same_numbers(threaded.path, shared.path)
    same_numbers(threaded.path, sent.path)


@pytest.mark.slow
def test_a_killed_worker_keeps_the_finished_parts_and_a_rerun_resumes(tmp_path):
    """Workers killed mid-run, on a scheduler that allows no failure (KilledWorker at
    once, as after a worker's walltime when retries are exhausted)."""
    config = _slow_study(tmp_path)
    out = tmp_path / "out"
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None)
    with cluster:
        with Client(cluster) as client:  # closed before the run: one client per process
            pids = list(client.run(os.getpid).values())
        killer = _when_parts_appear(out / "slow", lambda: [os.kill(pid, signal.SIGKILL) for pid in pids])
        with pytest.raises(RbstudyError) as killed:
            run_study(load_study(config), out, where=Where(scheduler=cluster.scheduler_address), quiet=True)
        killer.join()
    message = str(killed.value)
    assert "KilledWorker" in message and "rerun the same command to resume" in message
    assert "\n" not in message
    kept = _parts(out / "slow")
    # counted when the run ended: a worker already writing a part may still finish it
    told = int(re.search(r"(\d+) of 8 batches are kept", message).group(1))
    assert 1 <= told <= len(kept) < 8
    resumed = run_study(load_study(config), out, quiet=True)
    assert (resumed.computed, resumed.reused) == (8 - len(kept), len(kept))
    uninterrupted = run_study(load_study(config), tmp_path / "whole", quiet=True)
    same_numbers(uninterrupted.path, resumed.path)


@pytest.mark.slow
def test_a_scheduler_that_goes_away_keeps_the_finished_parts(tmp_path):
    config = _slow_study(tmp_path)
    out = tmp_path / "out"
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None)
    closer = _when_parts_appear(out / "slow", cluster.close)
    started = time.monotonic()
    with pytest.raises(RbstudyError, match="went away") as gone:
        run_study(load_study(config), out, where=Where(scheduler=cluster.scheduler_address), quiet=True)
    assert time.monotonic() - started < 60  # ends, without waiting out reconnection
    closer.join()
    kept = _parts(out / "slow")
    told = int(re.search(r"(\d+) of 8 batches are kept", str(gone.value)).group(1))
    assert told <= len(kept) and kept
    resumed = run_study(load_study(config), out, quiet=True)
    assert (resumed.computed, resumed.reused) == (8 - len(kept), len(kept))


@pytest.mark.slow
def test_workers_that_never_come_or_all_leave_end_the_run_in_one_line(tmp_path, capsys):
    config = _slow_study(tmp_path)
    out = tmp_path / "out"
    with LocalCluster(n_workers=0, dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert (
            main(
                [
                    "sweep",
                    str(config),
                    "--out",
                    str(out),
                    "--quiet",
                    "--scheduler",
                    address,
                    "--worker-wait",
                    "1",
                ]
            )
            == 1
        )
        error = capsys.readouterr().err.strip()
        assert f"no worker joined {address} for 1 s" in error and "\n" not in error
        assert "0 of 8 batches are kept" in error
        workers = _start_workers(address, 2, tmp_path)
        try:
            killer = _when_parts_appear(out / "slow", lambda: _stop(workers))
            with pytest.raises(RbstudyError, match=f"every worker left {address} for 2 s"):
                run_study(load_study(config), out, where=Where(scheduler=address, worker_wait=2), quiet=True)
            killer.join()
        finally:
            _stop(workers)
    assert _parts(out / "slow")


@pytest.mark.slow
def test_a_local_cluster_file_runs_the_study(tmp_path, capsys):
    config = _small_study(tmp_path)
    cluster = tmp_path / "cluster.yaml"
    cluster.write_text(yaml.safe_dump({"kind": "local", "jobs": 2}))
    assert (
        main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet", "--cluster", str(cluster)])
        == 0
    )
    threaded = run_study(load_study(config), tmp_path / "threaded", quiet=True)
    same_numbers(threaded.path, tmp_path / "out" / "small" / "small.nc")


@pytest.mark.slow
def test_a_sweep_with_workers_leaves_no_temporary_file(tmp_path):
    """Before: each ``--workers`` sweep left multiprocessing's ``pymp-*`` folder (its
    forkserver's socket) and dask's ``dask-scratch-space`` in the temporary folder, and so
    did a sweep refused after its forkserver started."""
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    config = write_study(
        tmp_path,
        name="tiny",
        scene={**abaqus_mapping(), "duration": 0.2},
        output={"interval": 0.02},
        sweep={"dt": [0.02, 0.01]},
    )
    env = {**os.environ, "TMPDIR": str(temporary), "PYTHONPATH": str(pathlib.Path(__file__).parents[1])}
    sweep = [
        sys.executable,
        "-m",
        "rbstudy",
        "sweep",
        "--workers",
        "2",
        "--out",
        str(tmp_path / "out"),
        "--quiet",
    ]
    done = subprocess.run([*sweep, str(config)], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "tiny" / "tiny.nc").is_file()
    refused = subprocess.run([*sweep, str(tmp_path / "none.yaml")], env=env, capture_output=True, timeout=300)
    assert refused.returncode == 1
    assert list(temporary.iterdir()) == []


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("kind: lsf\njobs: 2\n", "kind: expected one of local, slurm, pbs, got 'lsf'"),
        ("kind: slurm\n", "jobs: give either jobs"),
        ("kind: slurm\njobs: 2\nadaptive: {minimum: 0, maximum: 4}\n", "jobs: give either jobs"),
        ("kind: slurm\nadaptive: {minimum: 3, maximum: 2}\n", "adaptive.maximum: 2 is below"),
        ("kind: slurm\njobs: 0\n", "jobs: expected a whole number >= 1"),
        ("kind: pbs\njobs: 1\nqueue: short\n", "queue: unknown key; valid keys here: kind, jobs"),
        (
            "kind: local\njobs: 1\noptions: {no_such_option: 1}\n",
            "options.no_such_option: no keyword argument of LocalCluster or its workers; "
            "see the keyword arguments of LocalCluster",
        ),
        (
            "kind: local\njobs: 1\noptions: {memory_limit: lots}\n",
            "options.memory_limit: 'lots' is no amount of memory; give bytes with units",
        ),
        (
            "kind: slurm\njobs: 1\noptions: {memory: 4 gigs}\n",
            "options.memory: '4 gigs' is no amount of memory",
        ),
    ],
)
def test_a_bad_cluster_file_is_one_line_naming_the_key(tmp_path, text, message):
    path = tmp_path / "cluster.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as error:
        from rbstudy.pipeline.cluster import connect

        with connect(cluster=read_cluster_file(path)):
            pass
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


@pytest.mark.parametrize("kind", ["slurm", "pbs"])
def test_a_batch_cluster_file_becomes_dask_jobqueue_jobs(tmp_path, kind):
    """The options reach the job script; the jobs are asked for (no batch system here: the
    submission itself fails, which the cluster object reports, not rbstudy)."""
    jobqueue = pytest.importorskip("dask_jobqueue")
    from rbstudy.pipeline.cluster import JOB_CLUSTERS, _start

    path = tmp_path / "cluster.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "kind": kind,
                "adaptive": {"minimum": 0, "maximum": 3},
                "options": {"cores": 4, "processes": 4, "memory": "8GB", "walltime": "00:30:00"},
            }
        )
    )
    cluster = _start(read_cluster_file(path))
    try:
        assert isinstance(cluster, getattr(jobqueue, JOB_CLUSTERS[kind]))
        script = cluster.job_script()
        assert "00:30:00" in script and "--nworkers 4" in script
    finally:
        cluster.close()
