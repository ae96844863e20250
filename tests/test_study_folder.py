"""What a study folder holds is the study's: table files bound by name to their contents, and
one study (one config file) per folder."""

import contextlib
import hashlib
import multiprocessing
import os
import pathlib

import netCDF4
import pytest
from helpers import HOSTILE, HOSTILE_SHOWN, TERMINAL_CONTROLS, same_numbers, write_study

from rbstudy.archive.files import check_output_folder
from rbstudy.archive.load import open_results
from rbstudy.archive.owner import IDENTITY, OWNER
from rbstudy.cli import main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.pipeline.progress import Progress

NODE_TABLE = "id, x, y, z, mass\n1, 1.0, 0.2, 0.0, 2.0\n2, -0.8, 0.5, 0.1, 1.0\n3, 0.1, -1.2, 0.3, {}\n"
# Two tables of the same node ids that make different bodies, and two load tables of
# different knots: each swapped pair gives every case other numbers.
TABLES = {
    "nodes": (
        "scene.assembly.nodes",
        NODE_TABLE.format(1.5),
        NODE_TABLE.format(4.0),
        {
            "assembly": {"master": {"position": [0.1, 0.0, 0.2], "mass": 1.0}, "nodes": "a.csv"},
            "initial": {"angular_velocity": {"space": [0.4, 1.1, -0.6]}},
            "duration": 0.2,
        },
    ),
    "loads": (
        "scene.loads.moment_body.table",
        "0 0 0 0\n0.1 0 0 1\n",
        "0 0 0 0\n0.1 0.5 0 0\n0.2 0 -1 0\n",
        {
            "body": {"mass": 2.0, "inertia": [1.0, 2.0, 3.0]},
            "initial": {"angular_velocity": {"body": [0.3, 1.0, 0.2]}},
            "loads": {"moment_body": {"table": "a.csv"}},
            "duration": 0.2,
        },
    ),
}


def _table_study(folder, kind, swapped=False):
    """A study of two cases sweeping the two table files ``a.csv`` and ``b.csv`` of ``kind``
    in ``folder`` (their contents swapped when ``swapped``); returns the config's path."""
    folder.mkdir(exist_ok=True)
    key, first, second, scene = TABLES[kind]
    (folder / "a.csv").write_text(second if swapped else first)
    (folder / "b.csv").write_text(first if swapped else second)
    return write_study(
        folder,
        scene=scene,
        sweep={key: ["a.csv", "b.csv"]},
        run={"scheme": "rk4", "dt": 0.02},
        output={"interval": 0.1},
    )


@pytest.mark.slow
@pytest.mark.parametrize("kind", sorted(TABLES))
@pytest.mark.parametrize("keep_parts", [False, True], ids=["archive", "kept-parts"])
def test_swapped_table_contents_are_recomputed(tmp_path, kind, keep_parts):
    """Swap the contents of two swept table files: the rerun recomputes every batch and
    stores what a fresh run of the swapped files stores, whether it finds the old archive or,
    with the archive deleted, the old parts."""
    config = _table_study(tmp_path / "study", kind)
    out = tmp_path / "out"
    first = run_study(load_study(config), out, quiet=True, keep_parts=keep_parts)
    _table_study(tmp_path / "study", kind, swapped=True)
    if keep_parts:
        first.path.unlink()
    again = run_study(load_study(config), out, quiet=True, keep_parts=keep_parts)
    assert (again.up_to_date, again.reused, again.computed) == (False, 0, first.computed)
    fresh = run_study(
        load_study(_table_study(tmp_path / "fresh", kind, swapped=True)), tmp_path / "fresh_out", quiet=True
    )
    same_numbers(again.path, fresh.path)
    with pytest.raises(AssertionError):  # the swap changed the numbers: the check can fail
        same_numbers(
            again.path,
            run_study(
                load_study(_table_study(tmp_path / "old", kind)), tmp_path / "old_out", quiet=True
            ).path,
        )


def _refusal(config, folder, owner):
    """The one line that refuses ``config`` the study folder ``folder`` of ``owner``."""
    return (
        f"rbstudy: error: {config}: name: {folder} holds the study of another config of "
        f"this name, {owner.resolve()}; give this study another name or another --out "
        "(--force replaces that study)\n"
    )


def _folder_bytes(folder):
    return {
        path.relative_to(folder): path.read_bytes()
        for path in sorted(folder.rglob("*"))
        if path.is_file() and path.name not in (".lock", ".lock.pid")
    }


def test_a_second_zarr_study_of_the_same_name_is_refused_and_the_store_kept(tmp_path, capsys):
    """Two zarr configs of one name into one --out: the second is refused in one line, and
    the first's store, every file of it, is as it was."""
    output = {"interval": 0.01, "format": "zarr"}
    (tmp_path / "first").mkdir()
    (tmp_path / "second").mkdir()
    first = write_study(tmp_path / "first", name="top", output=output)
    leapfrog = {"scheme": "leapfrog", "dt": 0.01}
    second = write_study(tmp_path / "second", name="top", run=leapfrog, output=output)
    out = tmp_path / "out"
    assert main(["sweep", str(first), "--out", str(out), "--quiet"]) == 0
    folder = out / "top"
    kept = _folder_bytes(folder)
    assert any(path.parts[0] == "top.zarr" for path in kept)
    capsys.readouterr()
    assert main(["sweep", str(second), "--out", str(out), "--quiet"]) == 1
    assert capsys.readouterr().err == _refusal(second, folder, first)
    assert _folder_bytes(folder) == kept


@pytest.mark.slow
def test_a_second_config_of_the_same_name_is_refused_before_anything_changes(tmp_path, capsys):
    """Two config files of one name into one --out: the second is refused in one line naming
    both files and the fix, the first's archive and kept parts untouched; with --force it
    replaces them and says what it replaced. The first config, edited, is still its study."""
    (tmp_path / "first").mkdir()
    (tmp_path / "second").mkdir()
    first = write_study(tmp_path / "first", name="top")
    second = write_study(tmp_path / "second", name="top", run={"scheme": "leapfrog", "dt": 0.01})
    out = tmp_path / "out"
    assert main(["sweep", str(first), "--out", str(out), "--keep-parts", "--quiet"]) == 0
    folder = out / "top"
    kept = _folder_bytes(folder)
    assert any(name.suffix == ".npz" and name.parent.name == "parts" for name in kept)
    capsys.readouterr()
    assert main(["sweep", str(second), "--out", str(out), "--keep-parts", "--quiet"]) == 1
    assert capsys.readouterr().err == _refusal(second, folder, first)
    assert _folder_bytes(folder) == kept

    assert main(["sweep", str(second), "--out", str(out), "--keep-parts", "--quiet", "--force"]) == 0
    said = " ".join(capsys.readouterr().out.split())  # the line is broken at 100 columns
    assert (
        f"top: --force replaces the study of {first.resolve()} in {folder} (its archive and 1 kept part) "
    ) in said
    assert open_results(folder / "top.nc").attrs["config_path"] == str(second)
    first_parts = {name for name in kept if name.parent.name == "parts"}
    assert not first_parts & set(_folder_bytes(folder))  # the first's kept parts are gone
    assert main(["sweep", str(first), "--out", str(out), "--quiet"]) == 1  # now the second's
    assert capsys.readouterr().err == _refusal(first, folder, second)
    write_study(tmp_path / "second", name="top", run={"scheme": "leapfrog", "dt": 0.005})  # edited
    assert main(["sweep", str(second), "--out", str(out), "--quiet"]) == 0


def test_an_owner_record_of_control_characters_is_named_as_escapes(tmp_path, capsys):
    """The refusal names the folder's owner as its record says: escaped, what a terminal
    would obey (a record is a file anyone may have written), its carriage return too."""
    config = write_study(tmp_path, name="top")
    folder = tmp_path / "out" / "top"
    folder.mkdir(parents=True)
    (folder / OWNER).write_text(f"/elsewhere/{HOSTILE}.yaml\n{'0' * 64}\n")
    assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    error = capsys.readouterr().err
    assert error.startswith(f"rbstudy: error: {config}: name: ") and error.count("\n") == 1
    assert f", /elsewhere/{HOSTILE_SHOWN}.yaml; give this study" in error
    assert not TERMINAL_CONTROLS.search(error), repr(error)


def test_the_same_config_moved_to_another_file_is_the_same_study(tmp_path, capsys):
    """The folder is the config's, not only its file's: the same text moved to another file
    finds its results up to date (and that file owns the folder from then on), while another
    text of that name in the old place is refused."""
    (tmp_path / "here").mkdir()
    (tmp_path / "there").mkdir()
    first = write_study(tmp_path / "here", name="top")
    out = tmp_path / "out"
    assert main(["sweep", str(first), "--out", str(out), "--quiet"]) == 0
    moved = tmp_path / "there" / first.name
    moved.write_text(first.read_text())
    capsys.readouterr()
    assert main(["sweep", str(moved), "--out", str(out)]) == 0
    assert "is up to date" in " ".join(capsys.readouterr().out.split())
    write_study(tmp_path / "here", name="top", run={"scheme": "leapfrog", "dt": 0.01})
    assert main(["sweep", str(first), "--out", str(out), "--quiet"]) == 1
    assert capsys.readouterr().err == _refusal(first, out / "top", moved)


# What may be in the place of a study folder's owner record, the last with an archive and
# parts from before they named their config.
RECORD_KINDS = (
    "deleted",
    "fifo",
    "symlink to /dev/zero",
    "directory",
    "empty",
    "garbled",
    "archive from before",
)


def _mtimes(folder):
    return {path: path.stat().st_mtime_ns for path in [*folder.glob("*.nc"), *folder.glob("parts/*")]}


def _put_record(record, kind, folder):
    """Put ``kind`` of thing in the place of the study folder's owner record ``record``."""
    if record.is_dir() and not record.is_symlink():
        record.rmdir()
    else:
        record.unlink(missing_ok=True)
    if kind == "fifo":
        os.mkfifo(record)
    elif kind == "symlink to /dev/zero":
        record.symlink_to("/dev/zero")
    elif kind == "directory":
        record.mkdir()
    elif kind == "empty":
        record.write_text("")
    elif kind == "garbled":
        record.write_bytes(b"\xff\xfe not a path\n")
    elif kind == "archive from before":  # the record gone, the results without their identity
        for path in [folder / "top.nc", *folder.glob("parts/*.nc")]:
            with netCDF4.Dataset(path, "a") as nc:
                nc.delncattr(IDENTITY)


@pytest.mark.slow
def test_the_archive_and_parts_keep_their_study_without_the_owner_record(tmp_path, capsys):
    """With the owner record deleted or replaced by a FIFO, a symlink to /dev/zero, a
    directory, an empty or a garbled file, a second config of the same name is still refused
    in one line naming both files (the archive and the parts name their config), the first's
    archive and kept parts untouched; the first config itself resumes. An archive from
    before it named its config is taken for the config text and path it stores."""
    (tmp_path / "first").mkdir()
    (tmp_path / "second").mkdir()
    first = write_study(tmp_path / "first", name="top")
    second = write_study(tmp_path / "second", name="top", run={"scheme": "leapfrog", "dt": 0.01})
    out = tmp_path / "out"
    folder = out / "top"
    assert main(["sweep", str(first), "--out", str(out), "--keep-parts", "--quiet"]) == 0
    record = folder / OWNER
    owner = f"{first.resolve()}\n{hashlib.sha256(first.read_bytes()).hexdigest()}\n"
    for kind in RECORD_KINDS:
        _put_record(record, kind, folder)
        kept, mtimes = _folder_bytes(folder), _mtimes(folder)
        assert any(path.parent.name == "parts" for path in kept)
        capsys.readouterr()
        assert main(["sweep", str(second), "--out", str(out), "--keep-parts", "--quiet"]) == 1, kind
        assert capsys.readouterr().err == _refusal(second, folder, first), kind
        assert (_folder_bytes(folder), _mtimes(folder)) == (kept, mtimes), kind
        assert main(["sweep", str(first), "--out", str(out), "--keep-parts"]) == 0, kind
        assert "is up to date" in " ".join(capsys.readouterr().out.split()), kind
        assert _mtimes(folder) == mtimes, kind
        if kind != "directory":  # a folder in its place is left there
            assert record.read_text() == owner, kind


def test_a_rerun_removes_the_parts_left_beside_a_current_archive(tmp_path, capsys):
    """A sweep killed after its archive's rename, before it removed the parts, leaves them
    (as --keep-parts does): a rerun finds the archive current, removes the parts of its
    batches and their digests and says so, the archive untouched."""
    config = write_study(tmp_path, name="top")
    out = tmp_path / "out"
    assert main(["sweep", str(config), "--out", str(out), "--keep-parts", "--quiet"]) == 0
    folder = out / "top"
    archive = (folder / "top.nc").read_bytes(), (folder / "top.nc").stat().st_mtime_ns
    left = sorted(path.name for path in (folder / "parts").iterdir())
    assert len(left) == 2 and left[1] == left[0] + ".sha256"
    capsys.readouterr()
    assert main(["sweep", str(config), "--out", str(out)]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "top: removed 1 part file left beside its current archive, which holds them" in said
    assert "is up to date" in said
    assert not (folder / "parts").exists()
    assert ((folder / "top.nc").read_bytes(), (folder / "top.nc").stat().st_mtime_ns) == archive


def _sweep_in_child(config, out, start, stderr):
    """A forked child's sweep of ``config`` into ``out`` once ``start`` lets it go: its exit
    code, with what it printed on stderr written to the file ``stderr``."""
    start.wait()
    with open(stderr, "w") as stream, contextlib.redirect_stderr(stream):
        code = main(["sweep", str(config), "--out", str(out), "--quiet"])
    os._exit(code)


@pytest.mark.slow
def test_sweeps_into_one_new_nested_folder_at_once_are_told_another_holds_it(tmp_path):
    """Sweeps of one study into the same new nested --out, started at the same instant: one
    runs, every other finds it up to date or is told in one line that another sweep holds the
    study (none "File exists" or "its file system takes no new files", none removes what the
    one writes)."""
    config = write_study(tmp_path, name="top")
    assert main(["sweep", str(config), "--out", str(tmp_path / "warm"), "--quiet"]) == 0  # compiled
    fork = multiprocessing.get_context("fork")
    refused = 0
    for round_ in range(4):
        out = tmp_path / f"fresh{round_}" / "a" / "b"
        start = fork.Barrier(6)
        children = [
            fork.Process(target=_sweep_in_child, args=(config, out, start, tmp_path / f"err{round_}-{k}"))
            for k in range(6)
        ]
        for child in children:
            child.start()
        for child in children:
            child.join(timeout=120)
        errors = [(tmp_path / f"err{round_}-{k}").read_text() for k in range(6)]
        assert [child.exitcode for child in children].count(0) >= 1, errors
        for child, error in zip(children, errors, strict=True):
            if child.exitcode:
                assert child.exitcode == 1 and error.count("\n") == 1, error
                assert "another rbstudy sweep is writing this study" in error, error
                refused += 1
        assert (out / "top" / "top.nc").is_file()
        assert not (out / "top" / "parts").exists()
    assert refused, "no two sweeps ran at once: the race was never met"


def test_checking_a_new_out_makes_and_removes_no_folder_that_sweeps_at_once_share(tmp_path, monkeypatch):
    """The check of a new nested --out writes only in a private folder of the nearest existing
    one: a folder on the path itself, made and removed by the check of one sweep, is removed
    under another that found it (its lock met "No such file or directory" on a loaded CI)."""
    touched = []
    for name in ("mkdir", "rmdir"):
        original = getattr(pathlib.Path, name)

        def recorded(path, *args, _original=original, **kwargs):
            touched.append(path)
            return _original(path, *args, **kwargs)

        monkeypatch.setattr(pathlib.Path, name, recorded)
    out = tmp_path / "fresh" / "a" / "b"
    check_output_folder(out / "top")
    shared = {out / "top", *(out / "top").parents}
    assert touched and not shared.intersection(touched), touched
    assert list(tmp_path.iterdir()) == []


class _Phases(Progress):
    """A silent progress that records the phases a run shows."""

    def __init__(self):
        super().__init__("", "", quiet=True)
        self.phases = []

    def phase(self, what, total=None, unit=""):
        self.phases.append((what, total, unit))


def test_stored_parts_are_checked_and_said_to_be_only_where_there_are_some(tmp_path):
    """An empty folder has no parts to check: no "checking stored parts 2/2" (issue 41);
    the parts a killed run left (here: the archive gone) are checked, and counted."""
    study = load_study(write_study(tmp_path, name="top", sweep={"dt": [0.01, 0.005]}))
    first = _Phases()
    run_study(study, tmp_path / "out", keep_parts=True, progress=first)
    assert first.phases and not [p for p in first.phases if "checking stored parts" in p[0]]
    (tmp_path / "out" / "top" / "top.nc").unlink()
    again = _Phases()
    run = run_study(study, tmp_path / "out", progress=again)
    assert ("top: checking stored parts", 2, "parts") in again.phases
    assert run.computed == 0 and run.reused == 2
