"""Faults of the file system: an output folder that is a file, lies under one, or is /proc, a
read-only mount, an immutable folder and a full disk each end in one line naming the folder
(exit 1), with nothing printed before it and nothing half written; a read-only folder still
answers a rerun whose archive is current, and a sweep that filled its disk resumes.

The mounts and attributes need root (CI runs as root); where they cannot be made, the tests
that need them are skipped with the reason. Every mount and attribute is undone."""

import contextlib
import os
import shutil
import signal
import subprocess

import h5py
import pytest
import xarray as xr
from helpers import same_numbers, write_study

from rbstudy.archive.chunks import ChunkedArchive
from rbstudy.archive.files import write_dataset_atomic
from rbstudy.cli import main
from rbstudy.pipeline import execute
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

PAGE = 4096  # tmpfs counts whole pages: a sidecar of 100 bytes takes one
# /proc takes no new files, even from root
PROC_FOLDER = "/proc/rbstudy-results"


def _system(*command):
    """Run a mount or chattr command, or skip the test with the reason it could not."""
    if os.geteuid() != 0:
        pytest.skip(f"{command[0]} needs root")
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        pytest.skip(f"{' '.join(map(str, command))} failed here: {done.stderr.strip()}")


@contextlib.contextmanager
def _read_only(folder):
    """``folder`` mounted read-only over itself (a read-only mount: root cannot write either)."""
    _system("mount", "--bind", folder, folder)
    try:
        _system("mount", "-o", "remount,ro,bind", folder)
        yield folder
    finally:
        subprocess.run(["umount", folder], check=True)


@contextlib.contextmanager
def _immutable(folder):
    """``folder`` with the immutable attribute: no entry made, removed or renamed in it."""
    _system("chattr", "+i", folder)
    try:
        yield folder
    finally:
        subprocess.run(["chattr", "-i", folder], check=True)


@contextlib.contextmanager
def _tmpfs(folder, size):
    """A file system of ``size`` bytes mounted at ``folder``."""
    folder.mkdir()
    _system("mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", folder)
    try:
        yield folder
    finally:
        subprocess.run(["umount", folder], check=True)


def _one_line_only(capsys):
    """The error line of a command that must have printed nothing else, on either stream."""
    captured = capsys.readouterr()
    assert captured.out == "", captured.out
    error = captured.err.strip()
    assert "\n" not in error and "Traceback" not in error, error
    return error


def _open_in(folder):
    """The files in ``folder`` this process holds open (as /proc names them: a removed one
    ends in " (deleted)")."""
    found = []
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):  # closed since listed
            found.append(os.readlink(f"/proc/self/fd/{fd}"))
    return [name for name in found if name.startswith(f"{folder}/")]


def _verbs(tmp_path, out):
    """Every command that takes --out, pointed at ``out``; the results files need not exist:
    the folder is checked first."""
    config = write_study(tmp_path, name="small")
    absent = str(tmp_path / "small.nc")
    return [
        ["sweep", str(config), "--out", out],
        ["plot", absent, "--out", out],
        ["report", absent, "--out", out],
        ["conformance", "--cases", "t_handle", "--schemes", "euler", "--out", out],
    ]


def test_an_out_that_is_a_file_lies_under_one_or_is_proc_is_one_line_first(tmp_path, capsys):
    """Before, sweep printed its forecast line before the error, and plot and report ended in
    a traceback (exit 70)."""
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    cases = {
        str(blocker): f"--out {blocker}: is a file, not a folder",
        str(blocker / "sub"): f"--out {blocker}/sub: lies under the file {blocker}, not a folder",
        PROC_FOLDER: f"--out {PROC_FOLDER}: cannot write results there (its file system takes no new files)",
    }
    for out, message in cases.items():
        for verb in _verbs(tmp_path, out):
            assert main(verb) == 1, verb
            error = _one_line_only(capsys)
            assert error == f"rbstudy: error: {message}; choose another folder with --out", verb
    assert blocker.read_text() == "not a folder"


def test_a_read_only_or_immutable_out_is_one_line_first(tmp_path, capsys):
    for kind, protect, reason in (
        ("read-only", _read_only, "Read-only file system"),
        ("immutable", _immutable, "Operation not permitted"),
    ):
        out = tmp_path / kind
        out.mkdir()
        with protect(out):
            for verb in _verbs(tmp_path, str(out)):
                assert main(verb) == 1, verb
                assert _one_line_only(capsys) == (
                    f"rbstudy: error: --out {out}: cannot write results there ({reason}); "
                    "choose another folder with --out"
                ), verb
        assert list(out.iterdir()) == []


@pytest.fixture
def swept(tmp_path):
    """A one-batch study swept into ``out``: (config, its folder, the archive's bytes)."""
    config = write_study(tmp_path, name="small")
    done = run_study(load_study(config), tmp_path / "out", quiet=True)
    return config, done.path.parent, done.path.read_bytes()


def test_force_on_an_immutable_study_folder_is_one_line(swept, capsys):
    """Before: a PermissionError traceback making parts/ (exit 70)."""
    config, folder, archive = swept
    with _immutable(folder):
        assert main(["sweep", str(config), "--out", str(folder.parent), "--force"]) == 1
        assert _one_line_only(capsys) == (
            f"rbstudy: error: {folder}: cannot write results there (Operation not permitted); "
            "choose another folder with --out"
        )
    assert (folder / "small.nc").read_bytes() == archive


@pytest.mark.parametrize("frozen", ["study folder", "archive"])
def test_a_step_search_that_cannot_rewrite_its_archive_is_one_line_after_the_findings(swept, capsys, frozen):
    """The finished search goes into the archive, rewritten through a copy beside it: an
    immutable study folder (no working file, no copy) or an immutable archive (not
    replaced) is one line after the findings, the archive as it was and nothing left
    beside it."""
    config, folder, archive = swept
    before = sorted(path.name for path in folder.iterdir())
    with _immutable(folder if frozen == "study folder" else folder / "small.nc"):
        code = main(["sweep", str(config), "--out", str(folder.parent), "--find-step", "--quiet"])
        captured = capsys.readouterr()
    assert code == 1 and "small:" in captured.out  # the findings, printed first
    assert captured.err.strip() == (
        f"rbstudy: error: {folder}: cannot write results there (Operation not permitted); "
        "choose another folder with --out"
    )
    assert (folder / "small.nc").read_bytes() == archive
    kept = sorted(path.name for path in folder.iterdir())
    assert kept == before or frozen == "archive" and kept == sorted([*before, "search"])


def test_a_read_only_study_folder_answers_an_up_to_date_rerun(swept, capsys):
    """Reading is all an up-to-date rerun needs: it no longer dies taking its lock (exit 70).
    What would have to write (--force, another title to record) is one line, exit 1."""
    config, folder, archive = swept
    (folder / ".lock").unlink()  # as a copy of the results would come, or their first read
    sweep = ["sweep", "--out", str(folder.parent), "--quiet"]
    with _read_only(folder):
        assert main([*sweep, str(config)]) == 0
        out = " ".join(capsys.readouterr().out.split())  # the line is broken at 100 columns
        assert f"small: {folder}/small.nc is up to date (the same config and code)" in out
        for retitle in (False, True):
            if retitle:  # the same config, edited: its new title would be recorded
                config.write_text(config.read_text() + "title: another title\n")
            assert main([*sweep, str(config)] + ([] if retitle else ["--force"])) == 1
            assert _one_line_only(capsys) == (
                f"rbstudy: error: {folder}: cannot write results there (Read-only file "
                "system); choose another folder with --out"
            )
    assert (folder / "small.nc").read_bytes() == archive


def test_a_full_disk_before_the_first_write_is_one_line_and_leaves_nothing(tmp_path, capsys):
    """Before: the lock's pid met the full disk, a traceback (exit 70), and the study folder
    was left behind."""
    config = write_study(tmp_path, name="small")
    with _tmpfs(tmp_path / "disk", 16 * PAGE) as disk:
        (disk / "filler").write_bytes(bytes(16 * PAGE))
        assert main(["sweep", str(config), "--out", str(disk / "out"), "--quiet"]) == 1
        error = capsys.readouterr().err.strip()
        assert error == (
            f"rbstudy: error: {disk}/out/small: no space left on the file system "
            f"at {disk}; free space and rerun the same command (a sweep keeps its "
            "finished parts and resumes)"
        )
        assert sorted(path.name for path in disk.iterdir()) == ["filler"]


@pytest.mark.slow
def test_a_disk_filled_partway_keeps_its_parts_and_the_rerun_resumes(tmp_path, capsys, monkeypatch):
    """A real file system fills at the third of four parts: one line, the two finished
    parts kept and sealed, no temporary left; once the disk is larger the rerun reuses them,
    and the archive holds the numbers of an uninterrupted run."""
    config = write_study(tmp_path, name="small", sweep={"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005]})
    whole = run_study(load_study(config), tmp_path / "whole", quiet=True, keep_parts=True)
    part = max(path.stat().st_size for path in (whole.path.parent / "parts").glob("*.npz"))
    pages = -(-part // PAGE) + 1  # a part and its digest
    # the sweep's forecast would refuse the study on this disk: here another writer takes
    # the space once the forecast has passed
    monkeypatch.setattr(execute, "check_disk", lambda *args: None)
    monkeypatch.setattr(execute, "default_threads", lambda: 1)  # the parts one after another
    with _tmpfs(tmp_path / "disk", (1 + 2 * pages) * PAGE + part // 2) as disk:
        sweep = ["sweep", str(config), "--out", str(disk / "out")]
        assert main(sweep) == 1
        # stderr is no terminal: the run's start line, then the error in one line
        start, error = capsys.readouterr().err.strip().splitlines()
        assert start == "small: 4 cases in 4 batches"
        assert error.endswith(
            f": no space left on the file system at {disk}; free space "
            "and rerun the same command (a sweep keeps its finished parts "
            "and resumes)"
        )
        parts = disk / "out" / "small" / "parts"
        kept = sorted(parts.glob("*.npz"))
        # the archive is written beside the batches, and takes its share of the disk too
        assert 1 <= len(kept) <= 2 and len(list(parts.glob("*.sha256"))) == len(kept)
        assert not list(parts.glob(".*"))  # no temporary
        assert all(main(["verify", str(path)]) == 0 for path in kept)  # sealed, intact
        # HDF5 kept a failed temporary open, and its space taken (`netcdf_writer`): the
        # archive's, abandoned with more cached chunks than the disk holds, until it has room
        assert all(name.endswith(" (deleted)") for name in _open_in(disk))
        kept_times = [path.stat().st_mtime_ns for path in kept]
        capsys.readouterr()
        subprocess.run(["mount", "-o", "remount,size=4m", disk], check=True)
        assert main([*sweep, "--keep-parts"]) == 0
        run = 4 - len(kept)
        assert f"small: {run} batch{'es' * (run != 1)} run, {len(kept)} reused" in capsys.readouterr().out
        assert [path.stat().st_mtime_ns for path in kept] == kept_times  # reused, not rewritten
        same_numbers(whole.path, disk / "out" / "small" / "small.nc")
        assert not _open_in(disk)


@pytest.mark.slow
def test_a_disk_filled_while_a_zarr_store_is_written_keeps_its_parts_and_the_rerun_resumes(
    tmp_path, capsys, monkeypatch
):
    """A zarr study on a real file system that fills while its parts and its store are
    written: one line, the finished parts kept and sealed, no store and no temporary left;
    on a larger disk the rerun reuses the parts and the store holds the numbers of an
    uninterrupted run."""
    output = {"interval": 0.01, "format": "zarr"}
    sweep = {"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005]}
    config = write_study(tmp_path, name="small", sweep=sweep, output=output)
    whole = run_study(load_study(config), tmp_path / "whole", quiet=True, keep_parts=True)
    part = max(path.stat().st_size for path in (whole.path.parent / "parts").glob("*.npz"))
    monkeypatch.setattr(execute, "check_disk", lambda *args: None)  # as above
    monkeypatch.setattr(execute, "default_threads", lambda: 1)
    with _tmpfs(tmp_path / "disk", (1 + 2 * (-(-part // PAGE) + 1)) * PAGE + part // 2) as disk:
        sweep = ["sweep", str(config), "--out", str(disk / "out")]
        assert main([*sweep, "--quiet"]) == 1
        assert _one_line_only(capsys).endswith(
            f": no space left on the file system at {disk}; free space and rerun the same "
            "command (a sweep keeps its finished parts and resumes)"
        )
        folder = disk / "out" / "small"
        kept = sorted((folder / "parts").glob("*.npz"))
        assert 1 <= len(kept) < 4 and len(list((folder / "parts").glob("*.sha256"))) == len(kept)
        assert not (folder / "small.zarr").exists() and not list(folder.rglob(".*.tmp"))
        assert all(main(["verify", str(path)]) == 0 for path in kept)
        capsys.readouterr()
        subprocess.run(["mount", "-o", "remount,size=8m", disk], check=True)
        assert main(sweep) == 0
        run = 4 - len(kept)
        assert f"small: {run} batch{'es' * (run != 1)} run, {len(kept)} reused" in capsys.readouterr().out
        same_numbers(whole.path, folder / "small.zarr")
        assert main(["verify", str(folder / "small.zarr")]) == 0


def test_a_part_whose_digest_finds_no_room_is_not_left_half_finished(tmp_path, capsys, monkeypatch):
    """The disk holds the first part but not its digest: before, the part stayed without its
    digest (a rerun recomputes it, but it was left behind half finished, and with it the
    folders); now it goes too."""
    config = write_study(tmp_path, name="small")
    whole = run_study(load_study(config), tmp_path / "whole", quiet=True, keep_parts=True)
    part = next((whole.path.parent / "parts").glob("*.npz")).stat().st_size
    monkeypatch.setattr(execute, "check_disk", lambda *args: None)  # as above
    with _tmpfs(tmp_path / "disk", (1 + -(-part // PAGE)) * PAGE) as disk:  # the lock, a part
        assert main(["sweep", str(config), "--out", str(disk / "out"), "--quiet"]) == 1
        assert "no space left on the file system" in _one_line_only(capsys)
        assert list(disk.iterdir()) == []  # and so the folders this run made


def test_an_hdf5_error_on_a_full_disk_while_the_chunks_are_written_is_one_line(tmp_path, capsys, monkeypatch):
    """Before: h5py's direct chunk write failed on the full disk, its close then failed to
    flush (a RuntimeError that hid the first), and truncating the temporary freed the space
    that told a full disk: a traceback (exit 70). Here the disk is full while the archive's
    temporary holds its bytes, as on a tmpfs, which frees a truncated file's pages."""
    config = write_study(tmp_path, name="small", sweep={"scheme": ["euler", "midpoint"]})
    folder = tmp_path / "out" / "small"
    measured, truncate, truncated = shutil.disk_usage, os.truncate, []

    def usage(path):  # full from the archive's first write until its temporary is truncated
        written = list(folder.glob(".small.nc.*.tmp")) and not truncated
        return measured(path)._replace(free=0) if written else measured(path)

    def truncating(path, length):
        truncated.append(path)
        truncate(path, length)

    def write_fails(archive):
        raise RuntimeError(
            "Can't write unprocessed chunk data (file write failed: errno = 28, error "
            "message = 'No space left on device')"
        )

    closes, close = [], h5py.File.close

    def flush_fails_once(handle):
        if not closes:
            closes.append(handle)
            raise RuntimeError("Disable slist on flush dest failure failed (errno = 28)")
        close(handle)

    monkeypatch.setattr(shutil, "disk_usage", usage)
    monkeypatch.setattr(os, "truncate", truncating)
    monkeypatch.setattr(ChunkedArchive, "_write_oldest", write_fails)
    monkeypatch.setattr(h5py.File, "close", flush_fails_once)
    assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    mount = tmp_path
    while not os.path.ismount(mount):
        mount = mount.parent
    assert _one_line_only(capsys) == (
        f"rbstudy: error: {folder}: no space left on the file system at {mount}; free "
        "space and rerun the same command (a sweep keeps its finished parts and resumes)"
    )
    assert closes and truncated and not list(folder.glob(".*.tmp")) and not (folder / "small.nc").exists()


def test_a_ctrl_c_during_a_dataset_write_waits_for_the_file(tmp_path, monkeypatch):
    """A Ctrl-C while xarray writes a dataset (the step search's probes, after every batch)
    is raised once the file is in place: xarray, interrupted holding its netCDF lock, waited
    for that lock forever as it closed the file (a sweep --find-step hung so)."""
    write = xr.Dataset.to_netcdf

    def interrupted(dataset, *args, **kwargs):
        signal.raise_signal(signal.SIGINT)  # the user's Ctrl-C, mid-write
        return write(dataset, *args, **kwargs)

    monkeypatch.setattr(xr.Dataset, "to_netcdf", interrupted)
    written = xr.Dataset({"steps": ("probe", [4, 8, 16])})
    path = tmp_path / "steps.nc"
    # Python's own handler, as a sweep has it: dask_jobqueue's runner, which the cluster tests
    # import, puts its own (sys.exit) in its place for the whole process
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            write_dataset_atomic(written, path)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)
    assert xr.load_dataset(path)["steps"].values.tolist() == [4, 8, 16]
    assert [p.name for p in tmp_path.iterdir()] == ["steps.nc"]  # no temporary left
