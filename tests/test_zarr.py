"""The archive as a zarr v3 store (``output.format: zarr``, ``sweep --format zarr``): the same
dataset as the netCDF archive, proven per chunk by its checksums, rebuilt when damaged, left
alone when current, resumed after a kill to the numbers of an uninterrupted run."""

import collections
import contextlib
import json
import os
import pathlib
import shutil
import signal
import threading
import warnings
from dataclasses import replace

import numpy as np
import pytest
import xarray as xr
import yaml
from helpers import abaqus_mapping, sweep_until_a_batch_is_kept, write_study

from rbstudy.archive.folder import StudyFolder
from rbstudy.archive.parts import read_part, sidecar
from rbstudy.archive.provenance import global_attrs
from rbstudy.archive.zarr_regions import GENERATION, StoreReplaced, finish_regions
from rbstudy.cli import main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

SWEEP = {"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005], "inertia_ratio": [0.5, 2.0]}
# No scene axis swept: a variable of the scene alone is a scalar, which zarr gives no
# dimension names and reads back as a number.
ONE_SCENE = {"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005]}


def _zarr_config(folder, name="small", sweep=SWEEP, **kwargs):
    """A study config whose output.format is zarr."""
    path = write_study(folder, name=name, sweep=sweep, **kwargs)
    data = yaml.safe_load(path.read_text())
    data["output"]["format"] = "zarr"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _bare(dataset):
    """``dataset`` without encoding, and without its ``history`` (when each run ran)."""
    dataset = dataset.load()
    for variable in dataset.variables.values():
        variable.encoding = {}
    dataset.encoding = {}
    dataset.attrs.pop("history")
    return dataset


@pytest.mark.slow
@pytest.mark.parametrize("sweep", [SWEEP, ONE_SCENE], ids=["scenes", "one_scene"])
def test_the_store_holds_the_netcdf_archives_dataset(tmp_path, sweep):
    """The netCDF archive of a study and the zarr store built from the very same parts: xarray
    reads the same variables, values, coordinates and attributes from both (run_time too: the
    parts are one run's), and the store is sharded where a variable has several chunks."""
    config = write_study(tmp_path, name="small", sweep=sweep)
    netcdf = run_study(load_study(config), tmp_path / "out", quiet=True, keep_parts=True)
    assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--format", "zarr", "-q"]) == 0
    store = tmp_path / "out" / "small" / "small.zarr"
    assert store.is_dir() and netcdf.path.is_file()  # both, side by side
    expected = _bare(xr.open_dataset(netcdf.path))
    with warnings.catch_warnings():  # its metadata consolidated: read without a fallback
        warnings.simplefilter("error")
        found = _bare(xr.open_zarr(store))
    xr.testing.assert_identical(found, expected)
    assert found["status"].dtype == expected["status"].dtype
    assert json.loads((store / "quaternion" / "zarr.json").read_text())["zarr_format"] == 3


def test_shards_gather_chunks_only_where_a_variable_has_several():
    from rbstudy.archive.zarr_store import SHARD_BYTES, _shards

    assert _shards((2, 2, 51, 4), (2, 2, 51, 4), 2, 8, 4096) is None  # one chunk: one file
    # 100,000 x 500 cases of 8-byte values in chunks of 1 x 500: 100,000 chunks of 4 kB,
    # gathered into shards of SHARD_BYTES / 4 kB of them along the first dimension (it took
    # SHARD_BYTES / 500 chunks, shards of 8 x SHARD_BYTES, before its bytes were counted)
    shard = _shards((100_000, 500), (1, 500), 2, 8, 10**8)
    assert shard == (SHARD_BYTES // (500 * 8), 500) and shard[0] * 500 * 8 <= SHARD_BYTES
    # and no more cases than a batch's (4,096: 8 chunks of 500 cases), which then writes it
    # once, not once per batch of the many a shard would span
    assert _shards((100_000, 500), (1, 500), 2, 8, 4096) == (8, 500)


@pytest.mark.slow
def test_verify_names_a_damaged_chunk_and_a_rerun_rebuilds_the_store(tmp_path, capsys):
    config = _zarr_config(tmp_path)
    out = tmp_path / "out"
    first = run_study(load_study(config), out, quiet=True)
    store = first.path
    assert store.name == "small.zarr"
    assert main(["verify", str(store)]) == 0
    assert "intact" in capsys.readouterr().out
    chunk = store / "omega_error" / "c" / "0" / "0" / "0" / "0"
    damaged = bytearray(chunk.read_bytes())
    damaged[len(damaged) // 2] ^= 0xFF
    chunk.write_bytes(bytes(damaged))
    assert main(["verify", str(store)]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("rbstudy: error: ")
    assert "variable omega_error chunk (0, 0, 0, 0) differs from its checksum" in error
    assert main(["summary", str(store)]) == 1  # every reader refuses it
    capsys.readouterr()
    rebuilt = run_study(load_study(config), out, quiet=True)
    assert not rebuilt.up_to_date and "variable omega_error chunk (0, 0, 0, 0)" in rebuilt.archive_problems[0]
    assert main(["verify", str(store)]) == 0
    # and a chunk removed is named as missing
    chunk.unlink()
    assert main(["verify", str(store)]) == 1
    assert "variable omega_error chunk (0, 0, 0, 0) is missing" in capsys.readouterr().err


@pytest.mark.slow
def test_a_rerun_of_a_current_store_writes_nothing(tmp_path, capsys):
    config = _zarr_config(tmp_path)
    out = tmp_path / "out"
    first = run_study(load_study(config), out, quiet=True)
    files = {path: path.stat().st_mtime_ns for path in first.path.rglob("*")}
    again = run_study(load_study(config), out, quiet=True)
    assert again.up_to_date and again.computed == 0
    assert {path: path.stat().st_mtime_ns for path in first.path.rglob("*")} == files
    assert not (out / "small" / "small.nc").exists()
    # a changed title is redescribed in place: the values untouched, the store still intact
    text = config.read_text().replace("name: small", "name: small\ntitle: Another title")
    config.write_text(text)
    third = run_study(load_study(config), out, quiet=True)
    assert third.up_to_date
    assert xr.open_zarr(first.path, consolidated=False).attrs["title"] == "Another title"
    assert main(["verify", str(first.path)]) == 0


@pytest.mark.slow
def test_a_store_killed_mid_sweep_resumes_to_the_uninterrupted_result(tmp_path):
    sweep = {
        "scheme": ["rkmk4"],
        "dt": [0.01 / k for k in range(1, 11)],
        "inertia_ratio": {"linspace": [0.2, 2.0, 40]},
    }
    config = _zarr_config(tmp_path, name="long", sweep=sweep, scene={**abaqus_mapping(), "duration": 40.0})
    out = tmp_path / "out"
    process, parts = sweep_until_a_batch_is_kept(config, out)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    finished = len(list(parts.glob("*.npz.sha256")))
    assert 1 <= finished < 10, f"kill came too late to test resuming ({finished} parts)"
    assert not (out / "long" / "long.zarr").exists()  # a half store is never in its place
    half = out / "long" / ".long.zarr.x.tmp"  # as a kill mid-consolidation leaves
    (half / "status").mkdir(parents=True)
    (half / "zarr.json").write_text("{}")
    resumed = run_study(load_study(config), out, quiet=True)
    assert resumed.reused == finished and resumed.computed == 10 - finished
    assert not list((out / "long").glob(".*.tmp"))
    # against the netCDF archive, an uninterrupted run's by the other writer
    clean = run_study(replace(load_study(config), output_format="netcdf"), tmp_path / "clean", quiet=True)
    found = xr.open_zarr(resumed.path, consolidated=False).drop_vars("run_time").load()
    expected = xr.open_dataset(clean.path).drop_vars("run_time").load()
    for name, variable in expected.data_vars.items():
        np.testing.assert_array_equal(found[name].values, variable.values, err_msg=name)
    assert main(["verify", str(resumed.path)]) == 0


def test_an_unknown_format_is_one_line_naming_the_key_and_the_fix(tmp_path, capsys):
    path = write_study(tmp_path, output={"interval": 0.01, "format": "zarr2"})
    assert main(["validate", str(path)]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1
    assert error.startswith(f"rbstudy: error: {path}: output.format: unknown archive format 'zarr2'")
    assert "valid: netcdf" in error and "zarr" in error


def test_the_folder_of_a_zarr_study_holds_its_store(tmp_path):
    from rbstudy.archive.folder import StudyFolder

    study = load_study(_zarr_config(tmp_path))
    assert StudyFolder.of(tmp_path, study).archive == pathlib.Path(tmp_path) / "small" / "small.zarr"
    assert StudyFolder.of(tmp_path, load_study(write_study(tmp_path))).archive.suffix == ".nc"


def _positions(index, sizes):
    """numpy's orthogonal index of ``index`` (a slice or a list per dimension)."""
    return np.ix_(
        *[
            np.asarray(piece) if isinstance(piece, list) else np.arange(*piece.indices(size))
            for piece, size in zip(index, sizes, strict=True)
        ]
    )


@pytest.mark.parametrize("flush_every", [1, 3])
@pytest.mark.parametrize("open_bytes", [2**28, 64])
def test_units_hold_every_value_written_in_any_order_twice_or_spilled(
    tmp_path, monkeypatch, open_bytes, flush_every
):
    """The store's buffers of whole shards, against numpy's assignment of the same writes:
    slabs and lists of positions, out of order, some written twice (a variable of the scene
    alone gets its values from every part), with room for every open unit or for one, flushed
    after every write or every third (a unit spilled, then written again before it is
    stored: a part of many variables spills the units of the first while it writes the
    others; lost a row in two of a 12.8 MB shard before it was reopened)."""
    import zarr

    from rbstudy.archive import zarr_store

    monkeypatch.setattr(zarr_store, "OPEN_BYTES", open_bytes)
    group = zarr.create_group(store=str(tmp_path / "s.zarr"), zarr_format=3)
    array = group.create_array(
        "v", shape=(5, 7, 3), dtype="f8", chunks=(2, 3, 3), shards=(2, 6, 3), fill_value=np.nan
    )
    expected = np.full(array.shape, np.nan)
    units = zarr_store._Units({"v": array})
    rng = np.random.default_rng(3)
    writes = [(slice(0, 2), slice(0, 7)), ([2, 4], [1, 5, 6]), (slice(2, 5), slice(0, 4)), ([0], [2, 3])]
    writes += [(slice(3, 4), slice(4, 7)), ([2, 4], [4]), (slice(1, 3), slice(5, 7))]
    with zarr_store.ThreadPoolExecutor(2) as pool:
        for k, index in enumerate(writes, start=1):
            where = _positions(index, (5, 7))
            values = rng.normal(size=expected[where].shape)
            units.write("v", index, values)
            expected[where] = values
            if k % flush_every == 0:
                units.flush(pool)
        units.flush(pool, everything=True)
    np.testing.assert_array_equal(array[...], expected)


def _file_checksums(store, but=("run_time/",)):
    """The SHA-256 of each file of a sealed store (its integrity group's), but those under
    ``but`` (run_time: CPU seconds, never twice the same)."""
    import zarr

    group = zarr.open_group(str(store), mode="r", zarr_format=3, use_consolidated=False)
    return {k: v for k, v in group["integrity"].attrs["checksums"].items() if not k.startswith(but)}


def _long_zarr_config(folder):
    """Ten batches of a few seconds each: time for a kill while they run."""
    sweep = {
        "scheme": ["rkmk4"],
        "dt": [0.01 / k for k in range(1, 11)],
        "inertia_ratio": {"linspace": [0.2, 2.0, 40]},
    }
    return _zarr_config(folder, name="long", sweep=sweep, scene={**abaqus_mapping(), "duration": 40.0})


@pytest.mark.slow
def test_workers_write_their_regions_into_the_store_that_parts_would_make(tmp_path):
    """With --workers, each worker writes its batches into the store (a mark per batch, no
    part file, nothing sent back) and the store is, file for file, the one written from parts
    by one process (run_time, CPU seconds, aside): same chunks, same shards, same bytes."""
    from rbstudy.pipeline.cluster import Where

    study = load_study(_zarr_config(tmp_path))
    workers = run_study(study, tmp_path / "w", where=Where(workers=2), quiet=True, keep_parts=True)
    parts = tmp_path / "w" / "small" / "parts"
    assert workers.returned == 0 and workers.computed == len(study.batches) > 1
    assert not list(parts.glob("*.npz")) and not list(parts.glob("*.region"))  # marks gone with the store
    assert not (parts / "small.zarr").exists()  # the working store, sealed and moved into place
    local = run_study(study, tmp_path / "l", quiet=True)
    assert _file_checksums(workers.path) == _file_checksums(local.path)
    assert main(["verify", str(workers.path)]) == 0


def _children(pid):
    """Every process below ``pid``."""
    import psutil

    return psutil.Process(pid).children(recursive=True)


def _sweep_on_workers_until_a_batch_is_in(config, out):
    """``rbstudy sweep config --workers 2`` started, once its first batch is marked in the
    working store: the process, and the study's parts folder."""
    return sweep_until_a_batch_is_kept(config, out, "*.region.sha256", ("--workers", "2"), wait=180)


@pytest.mark.slow
def test_a_worker_killed_while_writing_loses_nothing_and_the_store_is_whole(tmp_path):
    """A worker killed (SIGKILL) once the workers write the store: its batch runs again on a
    worker the cluster starts in its place, each unit was written whole or not at all, and the
    store equals an uninterrupted one's."""
    config = _long_zarr_config(tmp_path)
    out = tmp_path / "out"
    process, parts = _sweep_on_workers_until_a_batch_is_in(config, out)
    # the workers: forked by the cluster's fork server, itself a child of the sweep
    workers = [
        child for child in _children(process.pid) if "forkserver" in " ".join(child.parent().cmdline())
    ]
    assert process.poll() is None and workers, "the sweep ended before a worker could be killed"
    marked = len(list(parts.glob("*.region.sha256")))
    workers[-1].kill()
    assert process.wait(timeout=600) == 0, process.stderr.read().decode()
    assert marked < 10  # batches were still to write when the worker died
    clean = run_study(load_study(config), tmp_path / "clean", quiet=True)
    assert _file_checksums(out / "long" / "long.zarr") == _file_checksums(clean.path)
    assert main(["verify", str(out / "long" / "long.zarr")]) == 0


@pytest.mark.slow
def test_a_sweep_on_workers_killed_resumes_from_the_batches_in_the_store(tmp_path):
    """The sweep killed (SIGKILL) while its workers write the store: the rerun keeps the
    batches marked in the working store, runs the others and seals the store of an
    uninterrupted run."""
    config = _long_zarr_config(tmp_path)
    out = tmp_path / "out"
    process, parts = _sweep_on_workers_until_a_batch_is_in(config, out)
    below = _children(process.pid)
    process.kill()
    process.wait()
    for child in below:  # its workers, which would outlive it until their scheduler's timeout
        with contextlib.suppress(Exception):
            child.kill()
    finished = len(list(parts.glob("*.region.sha256")))
    assert 1 <= finished < 10, f"kill came too late to test resuming ({finished} batches)"
    assert not (out / "long" / "long.zarr").exists()
    from rbstudy.pipeline.cluster import Where

    resumed = run_study(load_study(config), out, where=Where(workers=2), quiet=True)
    assert resumed.reused == finished and resumed.computed == 10 - finished
    clean = run_study(load_study(config), tmp_path / "clean", quiet=True)
    assert _file_checksums(resumed.path) == _file_checksums(clean.path)
    assert main(["verify", str(resumed.path)]) == 0


# The working store the workers write: what a rerun may trust of it. The workers' writes are
# made here, in this process, under a lock of this process (the cluster's takes a name too).
_UNIT_LOCKS = collections.defaultdict(threading.Lock)


def _unit_lock(name):
    return _UNIT_LOCKS[name]


@pytest.fixture(scope="module", params=[SWEEP, ONE_SCENE], ids=["scenes", "one_scene"])
def computed(tmp_path_factory, request):
    """A zarr study, its store written from parts by one process, and the values of each of
    its batches (read from the parts kept)."""
    folder = tmp_path_factory.mktemp("regions")
    study = load_study(_zarr_config(folder, sweep=request.param))
    run = run_study(study, folder / "local", quiet=True, keep_parts=True)
    parts = run.path.parent / "parts"
    values = {batch.id: read_part(parts / f"{batch.id}.npz", study.variables) for batch in study.batches}
    return study, run.path, values


def _working_folder(study, out):
    """The study's folder under ``out`` as a sweep on workers holds it, its working store
    defined (as the sweep does before any batch runs)."""
    folder = StudyFolder.of(out, study, unit_lock=_unit_lock)
    folder.make()
    folder.make_parts()
    folder.writer({}, started=None)  # not entered: it only defines the working store
    return folder


def _trusted(study, out):
    """The batches a rerun would take as written: batch id -> digest (None: run again)."""
    folder = StudyFolder.of(out, study, unit_lock=_unit_lock)
    return dict((batch.id, digest) for batch, digest in folder.checked(folder.stored(study.batches)))


def test_marks_of_a_store_defined_anew_count_for_nothing(computed, tmp_path):
    """A batch marked in a working store that is since lost and defined anew (a sweep killed,
    the store removed, a rerun killed after it defined its store): its mark, even if it
    survived, is not taken as written, and defining the store removes the marks there."""
    study, _, values = computed
    first = study.batches[0]
    folder = _working_folder(study, tmp_path)
    folder.part(first).write(values[first.id])
    assert _trusted(study, tmp_path)[first.id] is not None
    mark = folder.part_path(first.id)
    kept = {path: path.read_bytes() for path in (mark, sidecar(mark))}
    shutil.rmtree(folder.working_store)
    assert _trusted(study, tmp_path) == {}  # no store: no batch in it
    again = _working_folder(study, tmp_path)
    assert again.generation != folder.generation
    assert not mark.exists() and not sidecar(mark).exists()
    for path, data in kept.items():  # a mark that outlived its store, as a copy would bring back
        path.write_bytes(data)
    assert _trusted(study, tmp_path) == {first.id: None}
    assert again.damaged(study.batches) == 0  # of no use, but not a damaged batch


def test_a_sweep_killed_while_it_defines_the_store_leaves_none(computed, tmp_path, monkeypatch):
    """The store is defined in a temporary folder and renamed into place: a sweep killed
    while it writes the arrays leaves no store a rerun would keep, and the rerun's clearing
    removes the temporary."""
    import rbstudy.archive.files as files
    import rbstudy.archive.zarr_store as zarr_store

    study, _, _ = computed

    def killed(*args):  # after the root group (with its batches attribute) is written
        raise KeyboardInterrupt

    monkeypatch.setattr(zarr_store.Layout, "of", killed)
    # as SIGKILL would: the temporary's removal on the way out does not run either
    monkeypatch.setattr(files.shutil, "rmtree", lambda *args, **kwargs: None)
    with pytest.raises(KeyboardInterrupt):
        _working_folder(study, tmp_path)
    monkeypatch.undo()
    assert list((tmp_path / study.name / "parts").glob(".*.tmp"))  # half defined, aside
    folder = StudyFolder.of(tmp_path, study, unit_lock=_unit_lock)
    assert not folder.working_store.exists() and _trusted(study, tmp_path) == {}
    folder.clear_stale()
    assert list(folder.parts.iterdir()) == []


def test_a_worker_of_a_replaced_store_writes_nothing_into_it(computed, tmp_path):
    """A worker left running by a stopped sweep, whose store was since defined anew (another
    config, or a rerun after the store was lost), finds under its unit's lock that the store
    is not its own: it writes no cell and no mark."""
    study, _, values = computed
    first = study.batches[0]
    orphan = _working_folder(study, tmp_path).part(first)
    shutil.rmtree(tmp_path / study.name / "parts" / f"{study.name}.zarr")
    _working_folder(study, tmp_path)
    with pytest.raises(StoreReplaced):
        orphan.write(values[first.id])
    store = xr.open_zarr(tmp_path / study.name / "parts" / f"{study.name}.zarr", consolidated=False)
    assert int(store["energy_error"].notnull().sum()) == 0
    assert not pathlib.Path(orphan.path).exists()


@pytest.mark.slow
def test_the_sealed_store_from_regions_is_the_one_from_parts(computed, tmp_path):
    """Every batch written into its region here (a file a killed zarr write leaves among
    them), then the store finished as the sweep does: it is the store written from parts,
    file for file, with no working generation in its attributes and no mark left; the folder
    holds the archive and nothing of the working store."""
    study, from_parts, values = computed
    folder = _working_folder(study, tmp_path)
    marks = [folder.part(batch).write(values[batch.id]) for batch in study.batches]
    shard = next(folder.working_store.glob("energy_error/c/*"))
    (shard.parent / f"{shard.name}.0123abcd.partial").write_bytes(b"half a shard")
    arriving = [(None, digest, None) for digest in marks]
    finish_regions(study, arriving, folder.archive, global_attrs(study), working=folder.working_store)
    assert _file_checksums(folder.archive, but=()) == _file_checksums(from_parts, but=())
    assert GENERATION not in xr.open_zarr(folder.archive).attrs
    assert not list(folder.parts.glob("*.region*"))
    assert main(["verify", str(folder.archive)]) == 0


@pytest.mark.slow
def test_a_sweep_killed_while_it_seals_the_store_resumes_from_every_mark(computed, tmp_path, monkeypatch):
    """Killed once the working store is sealed, before it is renamed into place: the rerun
    trusts every mark (the store keeps its generation till then; without it the rerun ran
    every batch again), and sealing it then gives the store from parts."""
    import rbstudy.archive.zarr_regions as zarr_regions

    study, from_parts, values = computed
    folder = _working_folder(study, tmp_path)
    marks = [folder.part(batch).write(values[batch.id]) for batch in study.batches]
    arriving = [(None, digest, None) for digest in marks]
    sealing = zarr_regions.finish_store

    def killed(*args):
        sealing(*args)
        raise KeyboardInterrupt

    monkeypatch.setattr(zarr_regions, "finish_store", killed)
    with pytest.raises(KeyboardInterrupt):
        finish_regions(study, arriving, folder.archive, global_attrs(study), working=folder.working_store)
    assert _trusted(study, tmp_path) == dict(zip([batch.id for batch in study.batches], marks, strict=True))
    monkeypatch.setattr(zarr_regions, "finish_store", sealing)
    finish_regions(study, arriving, folder.archive, global_attrs(study), working=folder.working_store)
    assert _file_checksums(folder.archive, but=()) == _file_checksums(from_parts, but=())
    assert GENERATION not in xr.open_zarr(folder.archive).attrs


@pytest.mark.slow
def test_removing_the_parts_removes_the_marks_and_the_working_store(computed, tmp_path):
    """A sweep killed after the store was sealed leaves marks and, on a local rerun after a
    run on workers, a working store: beside a current archive, removing the parts removes
    them all."""
    study, _, values = computed
    folder = _working_folder(study, tmp_path)
    for batch in study.batches:
        folder.part(batch).write(values[batch.id])
    assert folder.remove_parts() == len(study.batches)
    assert not folder.parts.exists()
