"""Damaged results are never reused: thirteen kinds of corruption of a part or of the archive
are each recomputed (a part) or rebuilt (the archive) to the numbers of an undamaged run, and
`rbstudy verify` tells an intact archive from a damaged one."""

import pathlib
import shutil

import netCDF4
import numpy as np
import pytest
import xarray as xr
from helpers import same_numbers, write_study

from rbstudy.archive import checksums
from rbstudy.archive.checksums import GROUP
from rbstudy.archive.parts import SIDECAR_SUFFIX
from rbstudy.cli import main
from rbstudy.pipeline import config as config_module
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

VICTIM = "final_orientation_error"


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """A four-batch study run once with its parts kept: (config, results root, a copy of the
    undamaged folder)."""
    root = tmp_path_factory.mktemp("integrity")
    config = write_study(
        root,
        name="small",
        sweep={"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005], "inertia_ratio": [0.5, 2.0]},
    )
    run_study(load_study(config), root / "out", quiet=True, keep_parts=True)
    shutil.copytree(root / "out" / "small", root / "pristine")
    return config, root


@pytest.fixture
def study(clean):
    """A fresh copy of the undamaged study folder for one test: (config, root, folder)."""
    config, root = clean
    folder = root / "out" / "small"
    shutil.rmtree(folder)
    shutil.copytree(root / "pristine", folder)
    return config, root / "out", folder


def _data_offset(path, name):
    """Where the stored bytes of variable ``name`` begin in the (uncompressed) part file."""
    with np.load(path) as part:
        raw = np.ascontiguousarray(part[name]).tobytes()
    blob = path.read_bytes()
    offset = blob.find(raw)
    assert offset > 0, "the part's data are not stored contiguously"
    return offset, len(raw)


def _overwrite(path, offset, data):
    blob = bytearray(path.read_bytes())
    blob[offset : offset + len(data)] = data
    path.write_bytes(bytes(blob))


def _zero_data(path, other):
    offset, size = _data_offset(path, VICTIM)
    _overwrite(path, offset, bytes(size))


def _random_data(path, other):
    offset, size = _data_offset(path, "omega_body")
    _overwrite(path, offset, np.random.default_rng(1).bytes(size))


def _edit(path, change):
    """The netCDF file at ``path`` changed in place by ``change(nc)``."""
    with netCDF4.Dataset(path, "a") as nc:
        change(nc)


def _rewritten(part, change):
    """The part file ``part`` (numpy's .npz) written again with its arrays changed by
    ``change(arrays)``, as a hand or another program would."""
    with np.load(part) as stored:
        arrays = {name: stored[name].copy() for name in stored.files}
    change(arrays)
    with open(part, "wb") as file:
        np.savez(file, **arrays)


CORRUPTIONS = {
    "truncated": lambda path, other: path.write_bytes(path.read_bytes()[:-4096]),
    "garbage at the head": lambda path, other: _overwrite(path, 0, b"\xde\xad" * 64),
    "garbage at the tail": lambda path, other: path.write_bytes(path.read_bytes() + b"junk" * 99),
    "zeroed data": _zero_data,
    "random data": _random_data,
    "an edited value": lambda path, other: _rewritten(path, lambda part: part[VICTIM].__setitem__(0, 0.5)),
    "a wrong batch attribute": lambda path, other: _rewritten(
        path, lambda part: part.__setitem__("(batch)", np.array(other.stem))
    ),
    "another batch's part copied in": lambda path, other: shutil.copyfile(other, path),
    "a renamed variable": lambda path, other: _rewritten(
        path, lambda part: part.__setitem__("omega_b", part.pop("omega_body"))
    ),
    "an empty file": lambda path, other: path.write_bytes(b""),
    "a deleted part": lambda path, other: path.unlink(),
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", CORRUPTIONS)
def test_a_damaged_part_is_recomputed_never_reused(study, kind):
    config, out, folder = study
    reference = folder.parent / "undamaged.nc"
    (folder / "small.nc").rename(reference)  # the sweep resumes from its parts
    victim, other = sorted((folder / "parts").glob("*.npz"))[:2]
    CORRUPTIONS[kind](victim, other)
    again = run_study(load_study(config), out, quiet=True, keep_parts=True)
    assert (again.computed, again.reused) == (1, 3), kind
    assert again.damaged_parts == (0 if kind == "a deleted part" else 1)
    same_numbers(reference, again.path)
    assert main(["verify", str(victim)]) == 0  # the recomputed part is sealed again


def test_another_parts_file_and_digest_copied_in_is_recomputed(study):
    config, out, folder = study
    (folder / "small.nc").unlink()
    victim, other = sorted((folder / "parts").glob("*.npz"))[:2]
    for suffix in ("", SIDECAR_SUFFIX):  # the whole of another part, digest and all
        shutil.copyfile(f"{other}{suffix}", f"{victim}{suffix}")
    again = run_study(load_study(config), out, quiet=True, keep_parts=True)
    assert (again.computed, again.reused) == (1, 3)


@pytest.mark.slow
def test_a_tampered_archive_is_refused_by_verify_and_rebuilt_by_the_sweep(study, capsys):
    config, out, folder = study
    archive = folder / "small.nc"
    reference = folder.parent / "undamaged.nc"
    shutil.copyfile(archive, reference)
    assert main(["verify", str(archive)]) == 0
    assert "intact" in capsys.readouterr().out
    _edit(archive, lambda nc: nc[VICTIM].__setitem__((0, 0, 0), 0.5))
    assert main(["verify", str(archive)]) == 1
    error = capsys.readouterr().err.strip()
    assert f"{archive}: damaged: variable {VICTIM} differs from its checksum" in error
    assert "\n" not in error and "rerun its sweep" in error
    again = run_study(load_study(config), out, quiet=True, keep_parts=True)
    assert not again.up_to_date and again.archive_problems
    assert (again.computed, again.reused) == (0, 4)  # rebuilt from its intact parts
    same_numbers(reference, again.path)
    assert main(["verify", str(archive)]) == 0


def test_verify_checks_every_file_and_the_attributes_that_give_the_values_meaning(study, capsys):
    config, out, folder = study
    archive, edited = folder / "small.nc", folder / "edited.nc"
    shutil.copyfile(archive, edited)
    _edit(edited, lambda nc: nc.setncattr("accuracy_bound", 0.5))  # what "accurate" meant
    assert main(["verify", str(edited), str(archive)]) == 1
    captured = capsys.readouterr()
    assert f"{archive}: intact" in captured.out  # the second file is checked all the same
    assert "the global attributes study, batches, accuracy_bound differs" in captured.err
    _edit(edited, lambda nc: nc[f"/{GROUP}"].setncattr("checksums", "5"))
    assert main(["verify", str(edited)]) == 1
    assert "not what rbstudy writes" in capsys.readouterr().err
    part = sorted((folder / "parts").glob("*.npz"))[0]
    pathlib.Path(f"{part}{SIDECAR_SUFFIX}").unlink()
    assert main(["verify", str(part)]) == 1
    assert f"{part}: is one batch's part file, not a study's archive" in capsys.readouterr().err


def test_a_part_without_its_digest_is_unfinished_not_damaged(study):
    """A kill between a part's rename and its digest leaves it unsealed: recomputed, and not
    counted as damage."""
    config, out, folder = study
    (folder / "small.nc").unlink()
    part = sorted((folder / "parts").glob("*.npz"))[0]
    pathlib.Path(f"{part}{SIDECAR_SUFFIX}").unlink()
    again = run_study(load_study(config), out, quiet=True, keep_parts=True)
    assert (again.computed, again.reused, again.damaged_parts) == (1, 3, 0)


def test_verify_names_what_it_cannot_prove(study, tmp_path, capsys):
    config, out, folder = study
    plain = tmp_path / "plain.nc"
    xr.Dataset({"x": ("t", np.arange(3.0))}).to_netcdf(plain)
    assert main(["verify", str(plain)]) == 1
    assert "not an rbstudy archive: no study attribute; it holds x" in capsys.readouterr().err
    archive = folder / "small.nc"
    unsealed = tmp_path / "unsealed.nc"
    shutil.copyfile(archive, unsealed)
    _edit(unsealed, lambda nc: nc[f"/{GROUP}"].delncattr("checksums"))
    assert main(["verify", str(unsealed)]) == 1
    assert "cannot be proven intact: it carries no checksums" in capsys.readouterr().err
    _edit(archive, lambda nc: nc[f"/{GROUP}"].setncattr("part_checksums", '[["other", "sha256:0"]]'))
    assert main(["verify", str(archive)]) == 1
    assert "do not name the batches" in capsys.readouterr().err
    assert main(["verify", str(tmp_path / "absent.nc")]) == 1


def test_a_full_disk_is_one_line_and_keeps_the_finished_parts(tmp_path, capsys, monkeypatch):
    """The first two parts are written, the third meets a full disk (ENOSPC): one line naming
    the folder, the finished parts kept with their digests, and a rerun resumes from them."""
    import errno

    from rbstudy.archive import parts

    config = write_study(tmp_path, name="full", sweep={"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005]})
    written = []
    real_write = parts._write_arrays

    def write_until_full(path, arrays):
        if len(written) == 2:
            raise OSError(errno.ENOSPC, "No space left on device", path)
        written.append(path)
        return real_write(path, arrays)

    monkeypatch.setattr(parts, "_write_arrays", write_until_full)
    monkeypatch.setattr("rbstudy.pipeline.execute.os.cpu_count", lambda: 1)  # one at a time
    assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and "/full/parts: no space left on the file system at /" in error
    assert error.endswith(
        "free space and rerun the same command (a sweep keeps its finished parts and resumes)"
    )
    folder = tmp_path / "out" / "full" / "parts"
    assert len(list(folder.glob("*.npz.sha256"))) == 2 and not list(folder.glob(".*"))
    monkeypatch.undo()
    again = run_study(load_study(config), tmp_path / "out", quiet=True)
    assert (again.computed, again.reused) == (2, 2)


def test_the_seal_hashes_values_as_written_and_reads_back_only_the_rest(tmp_path, monkeypatch):
    """Parts copied in the grid's order (one scheme and dt, batches cutting its rows) are
    hashed as they are written: sealing reads back only the coordinates, and `rbstudy
    verify`, which reads everything, finds the same checksums."""
    monkeypatch.setattr(config_module, "BATCH_MAX_CASES", 4)
    config = write_study(
        tmp_path,
        name="rows",
        sweep={"spin": [1.0, 2.0, 3.0], "tilt": [5.0, 10.0, 15.0]},
        run={"scheme": "euler", "dt": 0.01},
    )
    study = load_study(config)
    assert len(study.batches) == 3  # 4 + 4 + 1 cases: two start inside a row
    read_back, read = [], checksums._update_values

    def reading(digest, variable):
        read_back.append(variable.name)
        read(digest, variable)

    monkeypatch.setattr(checksums, "_update_values", reading)
    run = run_study(study, tmp_path / "out", quiet=True)
    assert {"spin", "tilt"} <= set(read_back)  # the coordinates, written whole at the start
    assert not set(read_back) & set(study.variables)
    assert checksums.verify_archive(run.path).problems == ()


@pytest.mark.parametrize(
    ("index", "run"),
    [
        ((slice(1, 2), slice(3, 10)), (13, 7)),  # within a row
        ((slice(1, 3), slice(0, 10)), (10, 20)),  # whole rows
        ((slice(0, 1), slice(0, 10), slice(0, 4)), None),  # of another rank
        ((slice(1, 3), slice(3, 10)), None),  # the ends of two rows: a gap between
        ((slice(1, 2), [3, 4, 5]), None),  # a list: taken for scattered
    ],
)
def test_a_slab_is_one_run_of_positions_only_when_consecutive(index, run):
    assert checksums._run_of(index, (4, 10)) == run
