"""What the engine adapters' tests share (tests/test_engines.py and tests/test_<engine>.py):
the bodies they compare on, a run step by step, the largest difference of two schemes'
samples, and the example plug-in's linearised backward Euler."""

import importlib
import pathlib
import sys

import numpy as np
from helpers import LOADED, abaqus_mapping, write_study

from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics.driver import run_batch
from rbstudy.physics.scenes import param_rows
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import get_scheme

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "semi_implicit"


def make_scene(**mapping):
    return scene_from_mapping(mapping, "test")


def compared_scenes():
    """The Abaqus top, an asymmetric body from the same start, and a loaded body."""
    return [
        make_scene(**{**abaqus_mapping(), "duration": 2.0}),
        make_scene(**{**abaqus_mapping(inertia=[1.0, 2.0, 3.0]), "duration": 2.0}),
        make_scene(**LOADED),
    ]


def run(scheme, scenes, dt, n_steps):
    """Every step of ``scenes`` under ``scheme`` (a name or a `Scheme`) with its options'
    defaults: samples (B, n_steps + 1, N_STATE)."""
    chosen = get_scheme(scheme) if isinstance(scheme, str) else scheme
    return run_batch(
        chosen,
        np.array([body.state_row() for body in scenes]),
        param_rows(scenes),
        np.tile(chosen.option_row(), (len(scenes), 1)),
        dt,
        n_steps,
        1,
    ).samples


def difference(a, b, scenes, dt):
    """The largest difference (B,) of the samples of schemes ``a`` and ``b`` per scene."""
    return np.max(
        np.abs(simulate(scenes, a, dt, 0.01).output.samples - simulate(scenes, b, dt, 0.01).output.samples),
        axis=(1, 2),
    )


def example_scheme():
    """The example plug-in's compiled scheme, imported from its folder (not installed)."""
    sys.path.insert(0, str(EXAMPLE))
    try:
        return importlib.import_module("rbstudy_semi_implicit.compiled").SCHEME
    finally:
        sys.path.remove(str(EXAMPLE))


def swept_errors(tmp_path, schemes, origin, **sweep):
    """Sweep ``schemes`` on the asymmetric body over dt = 0.01, 0.005, 0.0025 (and the other
    ``sweep`` axes) through the CLI, check that every case finished and that the archive
    names ``origin`` as the schemes' provider; the final orientation errors."""
    import xarray as xr

    from rbstudy.cli import main

    config = write_study(
        tmp_path,
        name="engine",
        sweep={"scheme": schemes, "dt": [0.01, 0.005, 0.0025], **sweep},
        scene={**abaqus_mapping(inertia=[1.0, 2.0, 3.0]), "duration": 1.0},
    )
    assert main(["sweep", str(config), "--out", str(tmp_path), "--quiet"]) == 0
    with xr.open_dataset(tmp_path / "engine" / "engine.nc") as ds:
        assert (ds["status"] == 0).all()
        assert set(ds["scheme_origin"].values) == {origin}
        return ds["final_orientation_error"].load()
