"""The reference of a loaded body: two independent integrations (exact_split composed to
order 8, and DOP853), their difference archived as the reference's uncertainty, and order
fits that never run through an error within 10x of it. The composed reference is judged
against an extended-precision solution that shares no code with rbstudy's kernels."""

import numpy as np
import pytest
from extended_oracle import loaded_rotation
from helpers import write_study

from rbstudy.analysis.summary import UNCERTAINTY_FACTOR, fitted_order, scheme_rows
from rbstudy.archive.load import open_results
from rbstudy.inputs.scenes import scene_from_mapping, scene_table
from rbstudy.physics.metrics import orientation_error
from rbstudy.physics.references import (
    dop853_reference,
    reference_solution,
    reference_solutions,
    table_references,
)
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

TUMBLING = {
    "body": {"inertia": [1.0, 2.0, 3.0]},
    "initial": {
        "angular_velocity": {"body": [0.6, 1.5, 0.9]},
        "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
    },
}


def loaded(duration, **loads):
    return scene_from_mapping({**TUMBLING, "duration": duration, "loads": loads}, source="test")


def oracle(scene, step, **moments):
    """The extended-precision orientation at the end of ``scene``."""
    return loaded_rotation(
        scene.body.inertia, scene.quaternion, scene.omega_body, scene.duration, step, **moments
    )[0]


@pytest.mark.slow
def test_over_a_long_loaded_run_the_composed_reference_is_far_tighter_than_dop853():
    """40 s under a space-fixed moment: DOP853's error grows with the run, the composition's
    stays near round-off, and the archived uncertainty (their difference) is the larger of
    the two errors."""
    scene = loaded(40.0, moment_space=[0.0, 0.15, 0.0])
    times = np.arange(51) * 0.8
    reference = reference_solution(scene, times)
    assert reference.name == "exact_split_composition"
    exact = oracle(scene, 0.02, moment_space=(0.0, 0.15, 0.0))
    composed = orientation_error(reference.quaternion[-1], exact)
    checked = reference.uncertainty["orientation"]
    dop853 = orientation_error(dop853_reference(scene, times).quaternion[-1], exact)
    assert composed < 2e-12 and dop853 > 10.0 * composed, (composed, dop853)
    assert_tells_the_larger_error(checked, composed, dop853)


def assert_tells_the_larger_error(uncertainty, *errors):
    """The difference of two references lies within the smaller error of the larger one."""
    assert max(errors) / 2.0 <= uncertainty <= 2.0 * max(errors), (uncertainty, errors)


@pytest.mark.slow
def test_a_body_that_a_moment_spins_up_gets_a_step_for_its_fastest_spin():
    """A body moment spins the body up fivefold over 10 s, past the step chosen from the
    initial spin: the composition is rerun at a step fitted to the fastest spin. Compensated,
    it ends 5.1e-15 rad off (6.6e-12 with plain sums, whose every stage rounded the free
    body's rebuilt constants to an ulp as it crossed from one circulation to the other),
    DOP853 5.9e-13, and the uncertainty tells the larger."""
    scene = loaded(10.0, moment_body=[0.0, 0.0, 3.0])
    times = np.arange(11) * 1.0
    reference = reference_solution(scene, times)
    exact = oracle(scene, 0.005, moment_body=(0.0, 0.0, 3.0))
    assert np.linalg.norm(reference.omega_body[-1]) > 5.0 * np.linalg.norm(scene.omega_body)
    composed = orientation_error(reference.quaternion[-1], exact)
    dop853 = orientation_error(dop853_reference(scene, times).quaternion[-1], exact)
    assert composed < 1e-11
    assert_tells_the_larger_error(reference.uncertainty["orientation"], composed, dop853)


def test_knots_off_the_composition_s_steps_leave_dop853_the_reference():
    """A load table with a knot at 1/sqrt(2) s, which no step dividing the output interval 0.1 s
    puts on a step boundary: the composition would straddle the kink, so DOP853 (which
    restarts there) is the reference, unchecked; knots at 0.25 s and 1 s fit."""

    def tabled(knot):
        return scene_from_mapping(
            {
                **TUMBLING,
                "duration": 2.0,
                "loads": {"moment_body": {"table": [[knot, 0.0, 0.0, 0.0], [1.0, 0.6, -0.4, 1.2]]}},
            },
            source="test",
        )

    times = np.arange(21) * 0.1
    off = reference_solution(tabled(1.0 / np.sqrt(2.0)), times)
    assert off.name == "dop853" and off.uncertainty == {}
    on = reference_solution(tabled(0.25), times)
    assert on.name == "exact_split_composition" and 0.0 < on.uncertainty["orientation"] < 1e-11


def test_the_fit_skips_errors_within_ten_times_the_uncertainty():
    dts = 0.1 / 2.0 ** np.arange(6)
    errors = 3.0 * dts**4
    assert fitted_order(dts, errors, "orientation").used.all()
    uncertainty = np.full(dts.size, errors[-2] / UNCERTAINTY_FACTOR * 1.5)
    fit = fitted_order(dts, errors, "orientation", uncertainty)
    assert fit.used.tolist() == [True, True, True, True, False, False]
    assert fit.order == pytest.approx(4.0)
    assert fitted_order(dts, errors, "orientation", np.full(dts.size, np.nan)).used.all()


@pytest.fixture(scope="module")
def mixed_archive(tmp_path_factory):
    """rk4 over dt on the tumbling body, free and under a space-fixed moment."""
    folder = tmp_path_factory.mktemp("mixed")
    config = write_study(
        folder,
        name="mixed",
        sweep={"scene.loads.moment_space.1": [0.0, 0.1], "dt": {"halving": 0.1, "count": 5}},
        scene={**TUMBLING, "duration": 4.0, "loads": {"moment_space": [0.0, 0.0, 0.0]}},
        output={"interval": 0.1, "variables": ["final_orientation_error"]},
    )
    return open_results(run_study(load_study(config), folder / "out", quiet=True).path)


def test_the_uncertainty_is_archived_where_the_reference_is_integrated(mixed_archive):
    ds = mixed_archive
    assert ds["reference_uncertainty"].attrs["units"] == "rad"
    free, pushed = (ds["reference_uncertainty"].isel(loads_moment_space_1=k) for k in (0, 1))
    assert np.isnan(free).all()  # exact: nothing to check
    assert ((pushed > 0.0) & (pushed < 1e-11)).all()
    assert "reference_node_uncertainty" not in ds  # no nodes
    kinds = ds["reference"].attrs["flag_meanings"].split()
    assert {kinds[int(c)] for c in ds["reference"].isel(loads_moment_space_1=1).values.ravel()} == {
        "exact_split_composition"
    }


def test_the_summary_fits_no_order_through_an_uncertain_reference(mixed_archive):
    """The same archive, its uncertainty raised to just above the finest two errors of the
    loaded body: the fit leaves them out; raised above every error, there is no order."""
    ds = mixed_archive.isel(loads_moment_space_1=[1])
    (row,) = scheme_rows(ds)
    assert row["fit_dt"][0] == pytest.approx(0.1 / 16) and abs(row["order"][0] - 4.0) < 0.3
    errors = ds["final_orientation_error"].values.ravel()  # dt ascending: the finest first
    raised = ds.assign(
        reference_uncertainty=ds["reference_uncertainty"] * 0 + errors[1] / UNCERTAINTY_FACTOR * 1.5
    )
    (row,) = scheme_rows(raised)
    assert row["fit_dt"][0] == pytest.approx(0.1 / 4) and abs(row["order"][0] - 4.0) < 0.3
    swamped = ds.assign(reference_uncertainty=ds["reference_uncertainty"] * 0 + errors.max())
    assert scheme_rows(swamped)[0]["order"] is None


def test_a_table_s_references_are_those_of_its_scenes_bit_for_bit():
    """`table_references` reads a sweep's columns, `reference_solutions` the `Scene`s built
    from them: every kind (a symmetric top and an asymmetric body on parabolas, an axial
    moment, an integrated body) gives the same bits either way, in any order of rows."""
    # the first body symmetric within round-off: each Body symmetrises it, and so must the table
    inertia = np.array(
        [[1.0, 1.0 + 4e-13, 2.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [2.0, 1.0, 1.0]]
    )
    omega = np.array([[0.3, 0, 5], [0.3, 1, 0.2], [0, 0, 2], [0.3, 1, 0.2], [1, 0.1, 0.2]])
    moment = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0.5], [0.2, 0, 0], [0, 0, 0]])
    force = np.array([[0, 0, 1], [1, 0, 0], [0, 0, 0], [0, 0, 0], [0, 2, 0]])
    spec = {
        "body": {"inertia": list(inertia.T), "mass": 2.0},
        "duration": 0.5,
        "initial": {"angular_velocity": {"body": list(omega.T)}},
        "loads": {"moment_body": list(moment.T), "force_space": list(force.T)},
    }
    table = scene_table(spec, size=5)
    times = np.linspace(0.0, 0.5, 6)
    rows = np.array([3, 0, 4, 1, 2, 0])
    columns = table_references(table, rows, times)
    views = reference_solutions([table.scene(row) for row in rows], times)
    assert (
        [columns[k].name for k in range(len(rows))]
        == [view.name for view in views]
        == [
            "exact_split_composition",
            "symmetric_top",
            "symmetric_top",
            "exact_asymmetric",
            "axial_moment",
            "symmetric_top",
        ]
    )
    for k, view in enumerate(views):
        for name in ("quaternion", "omega_body", "position", "velocity"):
            assert np.array_equal(getattr(columns[k], name), getattr(view, name)), (k, name)
        assert columns[k].uncertainty == view.uncertainty
    assert 0.0 < columns[0].uncertainty["orientation"] < 1e-11  # checked by DOP853
