"""One time grid for every layer (issue 32): the schemes are sampled at the very times the
references are evaluated at, and the archive's scalar coordinates come from the runs, without
a case (and its scene) built to read one float."""

import numpy as np
import pytest
from helpers import write_study

from rbstudy.archive.layout import grid_coordinates
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.grid import Cases


def test_the_samples_are_taken_on_the_output_grid_of_the_references(asymmetric_scene):
    # 3 * 0.1 is 0.30000000000000004 in binary: times built from the step (k * 3 * dt) drift
    # from the output grid k * 0.3 on which the pipeline evaluates the references
    scene = asymmetric_scene.with_changes(duration=0.9)
    run = simulate([scene], "rk4", 0.1, 0.3)
    assert np.array_equal(run.time, np.arange(4) * 0.3)
    assert run.output.results["n_steps"][0] == 9


def test_the_archive_reads_an_unswept_scheme_and_dt_from_the_runs(tmp_path, monkeypatch):
    study = load_study(write_study(tmp_path, run={"scheme": "leapfrog", "dt": 0.005}))

    def no_case(cases, number):
        raise AssertionError("a case (with its scene) was built to read the scheme or dt")

    monkeypatch.setattr(Cases, "__getitem__", no_case)
    coords = grid_coordinates(study)
    assert coords["dt"][1] == pytest.approx(0.005) and coords["scheme"][1] == "leapfrog"
