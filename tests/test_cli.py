"""The command line: sweep writes a CF dataset; bad configs give one line, exit 2, no file."""

import math

import pytest
import xarray as xr

from rbstudy.cli import main


def test_sweep_writes_the_abaqus_dataset(tmp_path, capsys):
    assert main(["sweep", "configs/abaqus_top.yaml", "--out", str(tmp_path)]) == 0
    path = tmp_path / "abaqus_top" / "abaqus_top.nc"
    assert [p.name for p in path.parent.iterdir()] == ["abaqus_top.nc"]  # no temporary left
    with xr.open_dataset(path) as ds:
        assert ds.attrs["Conventions"] == "CF-1.11" and ds.attrs["reference"] == "symmetric_top"
        assert dict(ds.sizes) == {"time": 201, "axis": 3, "component": 4, "node": 3}
        assert "position" not in ds  # the top does not translate: absent, not NaN
        assert ds.omega_body.attrs["units"] == "rad s-1"
        assert ds.status.attrs["flag_meanings"] == "ok unstable not_converged"
        assert int(ds.status) == 0 and int(ds.iterations) == 200
        assert math.isclose(float(ds.precession_frequency_exact), 2 * math.pi)
        assert abs(float(ds.precession_frequency_error)) < 1e-2
        # node 4 sits on the symmetry axis, which nutates by 2 theta0 at most
        assert float(ds.node_displacement.sel(node="4").max()) < 0.05
    assert "precession frequency 6.281" in capsys.readouterr().out


@pytest.mark.parametrize("text, message", [
    ("name: x\nscene: {body: {inertia: [1, 1, 1]}}\nrun: {scheme: leapfrg, dt: 0.1}\n",
     "bad.yaml: run: unknown scheme 'leapfrg'; valid schemes: dop853, euler"),
    ("name: x\nscene: {body: {inertia: [1, 1, 1]}}\nrun: {scheme: rk4, dt: 0.03}\n"
     "output: {interval: 0.1}\n", "bad.yaml: run.dt: dt = 0.03 s does not divide the output"),
    ("name: x\nscene: {body: {inertia: [1, 1, 3]}}\nrun: {scheme: rk4, dt: 0.1}\n",
     "bad.yaml: scene.body.inertia: [1.0, 1.0, 3.0] violates the triangle inequality"),
    ("name: x\nscene: {body: {inertia: [1, 1, 1]}}\nrun: {scheme: rk4, dt: 0.1}\nsweeps: 1\n",
     "bad.yaml: sweeps: unknown key"),
    ("name: x\nscene: [1, 2\n", "bad.yaml: line 3: malformed YAML"),
])
def test_bad_configs_fail_in_one_line_with_nothing_written(tmp_path, capsys, text, message):
    config = tmp_path / "bad.yaml"
    config.write_text(text)
    out = tmp_path / "results"
    for verb in (["validate", str(config)], ["sweep", str(config), "--out", str(out)]):
        assert main(verb) == 2
        error = capsys.readouterr().err.strip()
        assert "\n" not in error and message.replace("bad.yaml", str(config)) in error, error
    assert not out.exists()


def test_unwritable_output_folder_is_one_line(tmp_path, capsys):
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    assert main(["sweep", "configs/abaqus_top.yaml", "--out", str(blocked)]) == 2
    error = capsys.readouterr().err.strip()
    assert "cannot write results there" in error and "\n" not in error


def test_schemes_lists_the_registry(capsys):
    assert main(["schemes"]) == 0
    listing = capsys.readouterr().out
    for name in ("euler", "leapfrog", "rk4", "midpoint", "hht", "splitting", "no_squish",
                 "rkmk4", "dop853"):
        assert f"\n{name} " in listing
