"""The archive as a user of xarray meets it (issue 30): dt ascending whatever order the
config gives, a swept scheme option labelled by the option, the provenance line, and archives
of rbstudy 0.3 (descending dt, checksums in the global attributes, the scene's variables on
every case) still read by plot, report, summary and verify. The default study's layout (the
scene's variables' dimensions, long_names, descriptions, the size of the attributes) is
checked in tests/test_pipeline.py."""

import pathlib
import re
import shutil
import subprocess

import netCDF4
import numpy as np
import pytest
from helpers import abaqus_mapping, write_study

from rbstudy.analysis.summary_forms import summary_document
from rbstudy.archive import layout
from rbstudy.archive.layout import grid_coordinates
from rbstudy.archive.provenance import source_text
from rbstudy.archive.reader import open_archive
from rbstudy.archive.variables import LONG_NAME_MAX, PER_SCENE
from rbstudy.cli import main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.schemes import BUILTIN

# Written by rbstudy 0.3.0 (the code at commit a5eacda) from legacy_v03.yaml beside it.
LEGACY = pathlib.Path(__file__).parent / "data" / "legacy_v03.nc"
CHECKOUT = pathlib.Path(__file__).resolve().parents[1]


def test_dt_is_ascending_whatever_order_the_config_gives(tmp_path):
    for given in ({"halving": 0.02, "count": 3}, [0.01, 0.02, 0.005], [0.005, 0.01, 0.02]):
        study = load_study(
            write_study(tmp_path, sweep={"dt": given, "scheme": ["euler"]}, output={"interval": 0.02})
        )
        dts = next(axis.values for d in study.dimensions for axis in d.axes if axis.target == "dt")
        assert dts == (0.005, 0.01, 0.02), given
        # the cases follow: the first case runs the smallest step
        assert study.cases[0].dt == 0.005


def test_a_swept_option_is_labelled_by_the_option_with_its_units(tmp_path):
    config = write_study(
        tmp_path,
        name="damping",
        scene={**abaqus_mapping(), "duration": 0.1},
        output={"interval": 0.02},
        run={"scheme": "hht", "dt": 0.02},
        sweep={"run.options.alpha": [0.0, -0.1]},
    )
    ds = open_archive(run_study(load_study(config), tmp_path / "out", quiet=True).path)
    assert ds.alpha.attrs == {
        "long_name": "HHT numerical dissipation alpha",
        "units": "1",
        "sweep_path": "run.options.alpha",
    }
    # a label (an axis order such as "213") has no units
    orders = load_study(
        write_study(
            tmp_path,
            name="orders",
            run={"scheme": "splitting", "dt": 0.01},
            sweep={"run.options.axis_order": ["123", "213"], "run.options.composition": [2, 4]},
        )
    )
    coordinates = grid_coordinates(orders)
    assert coordinates["axis_order"][2] == {
        "long_name": "order of the axes' free sub-flows",
        "sweep_path": "run.options.axis_order",
    }
    assert coordinates["composition"][2]["units"] == "1"


def test_every_option_of_rbstudy_s_schemes_has_a_label_for_the_archive():
    for scheme in BUILTIN.values():
        for option in scheme.options:
            assert 0 < len(option.long_name) <= LONG_NAME_MAX, (scheme.name, option.name)
            assert option.units in ("1", None), (scheme.name, option.name)


def test_source_names_the_version_and_the_commit_of_a_checkout(monkeypatch):
    if (CHECKOUT / ".git").exists():
        assert re.fullmatch(r"rbstudy 9\.9 \(commit [0-9a-f]{7,}(, modified)?\)", source_text("9.9"))

    def no_git(*args, **kwargs):
        raise FileNotFoundError("git")

    monkeypatch.setattr(subprocess, "run", no_git)
    assert source_text("9.9") == "rbstudy 9.9"


def _as_now(legacy):
    """The 0.3 archive's dataset in this version's layout: dt ascending, the variables of the
    scene alone along the scene's dimensions only (here inertia_ratio)."""
    now = legacy.sortby("dt")
    for name in PER_SCENE & set(now.data_vars):
        now[name] = now[name].isel(scheme=0, dt=0, drop=True)
    return now


def test_a_0_3_archive_reads_as_it_would_be_written_now():
    """The readers give the same answers whichever order dt is stored in and whether the
    scene's variables are copied over every case: the findings, the recommendation and the
    table of the 0.3 archive equal those of its data laid out as now."""
    legacy = open_archive(LEGACY)
    assert list(legacy.dt.values) == [0.02, 0.01, 0.005]  # as 0.3 wrote it
    assert legacy.inertia.dims == ("scheme", "dt", "inertia_ratio", "axis")
    now = _as_now(legacy)
    assert now.inertia.dims == ("inertia_ratio", "axis")
    assert summary_document(legacy) == summary_document(now)
    assert summary_document(now)["findings"][0]["text"].startswith("recommended: euler at dt=0.02 s")


@pytest.mark.slow
@pytest.mark.parametrize("verb", ["plot", "report", "summary", "verify"])
def test_every_reading_verb_reads_a_0_3_archive(verb, tmp_path, capsys):
    archive = tmp_path / "legacy_v03.nc"
    shutil.copyfile(LEGACY, archive)
    out = ["--out", str(tmp_path / "out")] if verb in ("plot", "report") else []
    assert main([verb, str(archive), *out]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    written = sorted(path.name for path in (tmp_path / "out").rglob("*.png")) if out else []
    if verb == "plot":
        assert "legacy_v03_convergence_orientation.png" in written
    if verb == "report":
        assert (tmp_path / "out" / "report.html").is_file()
    if verb == "summary":
        assert captured.out.startswith("recommended: euler at dt=0.02 s")
    if verb == "verify":
        assert captured.out.startswith(f"{archive}: intact (35 variables")


def test_a_damaged_0_3_archive_is_still_caught(tmp_path, capsys):
    archive = tmp_path / "legacy_v03.nc"
    shutil.copyfile(LEGACY, archive)
    with netCDF4.Dataset(archive, "a") as nc:
        nc["final_orientation_error"][0, 0, 0] = 0.5
    for verb in ("verify", "summary"):
        assert main([verb, str(archive)]) == 1
        error = capsys.readouterr().err
        assert error.count("\n") == 1
        assert "damaged: variable final_orientation_error differs from its checksum" in error


def test_the_scene_variables_of_a_zipped_option_and_body_lie_along_their_dimension(tmp_path):
    """A dimension that zips a scheme option with a body parameter changes the scene: the
    scene's variables lie along it; scheme and dt they never lie along."""
    config = write_study(
        tmp_path,
        name="zipped",
        scene={**abaqus_mapping(), "duration": 0.1},
        output={"interval": 0.02},
        run={"scheme": "hht", "dt": 0.02},
        sweep={
            "dt": [0.02, 0.01],
            "zip": {"pair": {"run.options.alpha": [0.0, -0.1], "scene.body.mass": [1.0, 2.0]}},
        },
    )
    ds = open_archive(run_study(load_study(config), tmp_path / "out", quiet=True).path)
    assert ds.status.dims == ("dt", "pair")
    assert ds.inertia.dims == ("pair", "axis") and ds.initial_spin.dims == ("pair",)
    assert np.array_equal(
        ds.initial_spin.values, np.linalg.norm(ds.omega_body.isel(time=0, dt=0).values, axis=-1)
    )
    assert layout.archive_dims(load_study(config), "inertia") == ("pair", "axis")
