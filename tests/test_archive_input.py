"""Archives are input: `plot`, `report` and `verify` refuse a damaged, foreign or crafted
archive in one line (exit 1, no traceback, nothing written anywhere), and no figure is ever
written outside its folder. Each crafted file is a copy of one small real archive."""

import json
import pathlib
import shutil
import zlib

import netCDF4
import numpy as np
import pytest
import xarray as xr
from helpers import HOSTILE, HOSTILE_SHOWN, TERMINAL_CONTROLS, abaqus_mapping, write_study

from rbstudy.analysis.plots import all_figures
from rbstudy.analysis.report import write_report
from rbstudy.archive.checksums import GROUP, seal_archive, verify_archive
from rbstudy.archive.load import open_results
from rbstudy.archive.variables import BOOKKEEPING
from rbstudy.cli import main
from rbstudy.errors import InputError
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

VERBS = ("plot", "report", "verify")
# Damage that `verify` has refused since it exists (tests/test_integrity.py); new here for
# `plot` and `report`.
DAMAGE = ("an edited value", "a bit flipped", "a zeroed block")


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """A real archive of two schemes at two steps over 0.2 s."""
    root = tmp_path_factory.mktemp("archive")
    config = write_study(
        root,
        name="tiny",
        scene={**abaqus_mapping(), "duration": 0.2},
        output={"interval": 0.02},
        sweep={"scheme": ["euler", "rk4"], "dt": [0.02, 0.01]},
    )
    return run_study(load_study(config), root / "out", quiet=True).path


def _edit(path, change):
    with netCDF4.Dataset(path, "a") as nc:
        change(nc)


def _stored_at(path, name):
    """Where the stored bytes of variable ``name`` begin in the file, and how many: raw for
    a contiguous variable, else its one chunk as the archive compresses it (shuffle, zlib)."""
    with netCDF4.Dataset(path) as nc:
        variable = nc[name]
        values = np.ascontiguousarray(variable[...].filled(np.nan))
        compressed = variable.chunking() != "contiguous"
    stored = values.tobytes()
    if compressed:
        shuffled = np.frombuffer(stored, np.uint8).reshape(-1, values.itemsize).T.tobytes()
        stored = zlib.compress(shuffled, 4)
    offset = path.read_bytes().find(stored)
    assert offset > 0, f"{name}'s stored bytes were not found"
    return offset, len(stored)


def _overwrite(path, offset, data):
    blob = bytearray(path.read_bytes())
    blob[offset : offset + len(data)] = data
    path.write_bytes(bytes(blob))


def _flip_a_bit(path):
    offset, _ = _stored_at(path, "dt")  # plain float64 values: the file still reads
    _overwrite(path, offset, bytes([path.read_bytes()[offset] ^ 1]))


def _zero_a_block(path):
    offset, size = _stored_at(path, "orientation_error")  # compressed: HDF5 cannot read it
    _overwrite(path, offset, bytes(size))


def _rewritten(path, change):
    """The archive read and written back by xarray after ``change`` (its attributes, the
    old checksums included, carried along)."""
    dataset = change(open_results(path))
    path.unlink()
    dataset.to_netcdf(path)


def _text_in_place_of_numbers(ds):
    return ds.assign(
        final_orientation_error=(("scheme", "dt"), np.array([["a", "b"], ["c", "d"]], dtype=object))
    )


def _bookkeeping_of_other_shapes(path, source="a hand"):
    """The issue's file: a study attribute and the bookkeeping names, other shapes."""
    path.unlink()
    xr.Dataset(
        {name: ("x", np.zeros(3)) for name in BOOKKEEPING}, attrs={"study": "fake", "source": source}
    ).to_netcdf(path)


# name -> (how the copy is crafted, what the error line says after the file's name)
CRAFTED = {
    "an edited value": (
        lambda path: _edit(path, lambda nc: nc["final_orientation_error"].__setitem__((0, 0), 0.5)),
        ": damaged: variable final_orientation_error differs from its checksum",
    ),
    "a bit flipped": (_flip_a_bit, ": damaged: variable dt differs from its checksum"),
    "a zeroed block": (_zero_a_block, ": damaged: it cannot be read as netCDF (NetCDF: HDF error)"),
    "a study up two folders": (
        lambda path: _edit(path, lambda nc: nc.setncattr("study", "../../escaped")),
        ": study: not an rbstudy archive: the study attribute '../../escaped' is not a study "
        "name (letters, digits, '-' and '_' only, at most 215 bytes)",
    ),
    "a study with a slash": (
        lambda path: _edit(path, lambda nc: nc.setncattr("study", "sub/escaped")),
        ": study: not an rbstudy archive: the study attribute 'sub/escaped' is not",
    ),
    "no dt": (
        lambda path: _rewritten(path, lambda ds: ds.drop_vars("dt")),
        ": not an rbstudy archive: it lacks dt (written by rbstudy",
    ),
    "dt along another dimension": (
        lambda path: _rewritten(
            path, lambda ds: ds.drop_vars("dt").rename_dims(dt="step").assign(dt=("x", [0.1, 0.2, 0.3]))
        ),
        ": dt: not an rbstudy archive: dt lies along (x), not a single value (swept: scheme, step)",
    ),
    "text in place of numbers": (
        lambda path: _rewritten(path, _text_in_place_of_numbers),
        ": final_orientation_error: not an rbstudy archive: final_orientation_error holds text, not float64",
    ),
    "the bookkeeping names of other shapes": (
        _bookkeeping_of_other_shapes,
        ": not an rbstudy archive: it lacks scheme, dt (written by a hand)",
    ),
    "a writer of control characters": (
        lambda path: _bookkeeping_of_other_shapes(path, source=HOSTILE),
        f": not an rbstudy archive: it lacks scheme, dt (written by {HOSTILE_SHOWN})",
    ),
    "a YAML file": (
        lambda path: path.write_text("name: tiny\nrun: {scheme: rk4}\n"),
        ": not an rbstudy archive: not a netCDF file",
    ),
}


def _crafted(archive, folder, kind):
    path = folder / "input" / "tiny.nc"
    path.parent.mkdir(parents=True)
    shutil.copyfile(archive, path)
    CRAFTED[kind][0](path)
    return path


def _files(folder):
    return sorted(p for p in pathlib.Path(folder).rglob("*") if p.is_file())


@pytest.mark.parametrize(
    ("kind", "verb"),
    [(kind, verb) for kind in CRAFTED for verb in VERBS if not (verb == "verify" and kind in DAMAGE)],
)
def test_a_damaged_or_foreign_archive_is_one_line_and_nothing_is_written(
    archive, tmp_path, capsys, kind, verb
):
    path = _crafted(archive, tmp_path, kind)
    out = tmp_path / "top" / "middle" / "out"  # "../../escaped" would land in top/
    before = _files(tmp_path)
    assert main([verb, str(path)] + (["--out", str(out)] if verb != "verify" else [])) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "Traceback" not in error, error
    assert f"rbstudy: error: {path}{CRAFTED[kind][1]}" in error
    assert not TERMINAL_CONTROLS.search(error), repr(error)
    assert _files(tmp_path) == before and not (tmp_path / "top").exists()


@pytest.mark.parametrize("form", ("text", "md", "csv"))
def test_a_scheme_name_of_control_characters_is_summarised_as_escapes(archive, tmp_path, capsys, form):
    """A crafted archive whose scheme is named to set the terminal's title and clear its
    screen: the summary shows the name, escaped (json's own rules escape it as \\u001b)."""
    path = _crafted(archive, tmp_path, "an edited value")  # an edit: read with --no-verify
    _rewritten(path, lambda ds: ds.assign_coords(scheme=[HOSTILE, "rk4"]))
    assert main(["summary", str(path), "--no-verify", "--format", form]) == 0
    out = capsys.readouterr().out
    assert not TERMINAL_CONTROLS.search(out), repr(out)
    assert (HOSTILE_SHOWN[:20] if form == "text" else HOSTILE_SHOWN) in out  # text cuts long names


@pytest.mark.slow
@pytest.mark.parametrize("verb", ("plot", "report"))
def test_only_no_verify_reads_an_edited_archive_and_never_an_unreadable_one(archive, tmp_path, capsys, verb):
    assert main([verb, str(archive), "--out", str(tmp_path / "intact")]) == 0
    path = _crafted(archive, tmp_path / "edited", "an edited value")
    out = tmp_path / "out"
    assert main([verb, str(path), "--out", str(out)]) == 1 and not out.exists()
    assert main([verb, str(path), "--out", str(out), "--no-verify"]) == 0
    assert list(out.rglob("tiny_*.png"))
    zeroed = _crafted(archive, tmp_path / "zeroed", "a zeroed block")
    capsys.readouterr()
    assert main([verb, str(zeroed), "--out", str(tmp_path / "out2"), "--no-verify"]) == 1
    error = capsys.readouterr().err
    assert error == (
        f"rbstudy: error: {zeroed}: damaged: it cannot be read (NetCDF: HDF "
        "error); rerun its sweep (rbstudy sweep <config>): a damaged archive is "
        "rebuilt\n"
    )
    assert not (tmp_path / "out2").exists()


def test_no_figure_is_written_or_deleted_outside_its_folder(archive, tmp_path):
    """The last guard, for a dataset that did not come through the checked opening."""
    folder = tmp_path / "a" / "b"
    folder.mkdir(parents=True)
    victim = tmp_path / "a" / "escaped_convergence_orientation.png"  # where ../ points
    victim.write_bytes(b"a user's file")
    dataset = open_results(archive).assign_attrs(study="../escaped")
    with pytest.raises(InputError, match="would be written outside it"):
        all_figures(dataset, folder)
    assert _files(tmp_path) == [victim] and victim.read_bytes() == b"a user's file"
    with pytest.raises(InputError, match="it names a folder"):  # not even the report's marker
        write_report(dataset, folder / "report")
    assert _files(tmp_path) == [victim]


def _sealed_anew(path, change):
    """The archive after ``change`` (of its path), its checksums computed anew, as a hostile
    or buggy writer would leave it: `verify` finds every variable matching its checksum."""
    with netCDF4.Dataset(path) as nc:
        parts = json.loads(nc.groups[GROUP].getncattr("part_checksums"))
    change(path)
    seal_archive(path, parts)


def _emptied(dim):
    def change(path):
        dataset = open_results(path).isel({dim: slice(0, 0)})
        for variable in dataset.variables.values():
            variable.encoding.clear()  # chunks of the old sizes fit no empty dimension
        path.unlink()
        dataset.to_netcdf(path)

    return change


# name -> (how the sealed copy is changed, what the error line says after the file's name)
ODD_CONTENT = {
    "a status of -1": (
        lambda path: _edit(path, lambda nc: nc["status"].__setitem__((0, 0), -1)),
        ": status: not an rbstudy archive: status holds -1; its values are 0 (ok), 1 "
        "(unstable), 2 (not_converged)",
    ),
    "a status of 3": (
        lambda path: _edit(path, lambda nc: nc["status"].__setitem__((1, 1), 3)),
        ": status: not an rbstudy archive: status holds 3; its values are 0 (ok),",
    ),
    "an accuracy flag of 7": (
        lambda path: _edit(path, lambda nc: nc["accuracy"].__setitem__((0, 1), 7)),
        ": accuracy: not an rbstudy archive: accuracy holds 7; its values are 0 (accurate), "
        "1 (inaccurate), 2 (failed), 3 (unjudged)",
    ),
    "a text accuracy_bound": (
        lambda path: _edit(path, lambda nc: nc.setncattr("accuracy_bound", "tight")),
        ": accuracy_bound: not an rbstudy archive: the accuracy_bound attribute holds "
        "'tight', not a number above 0",
    ),
    "an accuracy_bound of 0": (
        lambda path: _edit(path, lambda nc: nc.setncattr("accuracy_bound", 0.0)),
        ": accuracy_bound: not an rbstudy archive: the accuracy_bound attribute holds 0.0,",
    ),
    "no cases": (_emptied("dt"), ": dt: not an rbstudy archive: it holds no cases (dt has length 0)"),
    "no output times": (
        _emptied("time"),
        ": time: not an rbstudy archive: it holds no output times (time has length 0)",
    ),
    "a study name of 300 characters": (
        lambda path: _edit(path, lambda nc: nc.setncattr("study", "a" * 300)),
        f": study: not an rbstudy archive: the study attribute '{'a' * 79} is not a study "
        "name (letters, digits, '-' and '_' only, at most 215 bytes)",
    ),
}


@pytest.mark.parametrize("kind", ODD_CONTENT)
def test_an_archive_sealed_anew_with_odd_content_is_refused_by_every_verb(archive, tmp_path, capsys, kind):
    """Before: each passed `verify`; a status of -1 was summarised as "not_converged: the
    implicit solver failed", a text accuracy_bound, no cases or no output times ended
    `summary`, `plot` or `report` in a traceback, and a 300-character study name `plot`'s
    figure files (File name too long)."""
    path = tmp_path / "input" / "tiny.nc"
    path.parent.mkdir()
    shutil.copyfile(archive, path)
    _sealed_anew(path, ODD_CONTENT[kind][0])
    assert verify_archive(path).problems == ()  # its checksums match
    before = _files(tmp_path)
    for verb in ("verify", "summary", "plot", "report"):
        out = ["--out", str(tmp_path / "out")] if verb in ("plot", "report") else []
        assert main([verb, str(path), *out]) == 1, verb
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.count("\n") == 1, captured
        assert captured.err.startswith(f"rbstudy: error: {path}{ODD_CONTENT[kind][1]}"), captured.err
    assert _files(tmp_path) == before
