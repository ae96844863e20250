"""Compositions of the symmetric schemes (orders 4, 6, 8) and `exact_split`: observed orders,
exactness for free bodies against an independent 40-digit solution, invariants, and what the
archive and the summary say of a swept composition."""

import numpy as np
import pytest
from free_body_mp import angle_between, exact_state
from helpers import LOADED, write_study

from rbstudy.analysis.summary import scheme_rows
from rbstudy.archive.load import open_results
from rbstudy.errors import SchemeError
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.physics.metrics import asymptotic_order, momentum_error, omega_error, orientation_error
from rbstudy.physics.references import dop853_reference, reference_solution
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.schemes import BUILTIN, COMPOSITION_ORDERS, composition_reach, get_scheme
from rbstudy.schemes._composition import stage_weights

ORDER_TOLERANCE = 0.3  # the bound on a composition's observed order
COMPOSABLE = [
    name for name, scheme in BUILTIN.items() if any(option.name == "composition" for option in scheme.options)
]


def fitted(dts, errors, floor=1e-11):
    """The observed order over the points above ``floor`` (the reference's own error)."""
    order, used, _ = asymptotic_order(np.asarray(dts), np.asarray(errors), floor=floor)
    assert used.sum() >= 3, f"too few points in the asymptotic range: {errors}"
    return order


def test_the_symmetric_schemes_and_exact_split_compose():
    assert COMPOSABLE == ["exact_split", "lgvi", "midpoint", "no_squish", "simo_wong", "splitting"]
    assert COMPOSITION_ORDERS == (2, 4, 6, 8)


@pytest.mark.parametrize("order", [4, 6, 8])
def test_the_weights_meet_the_order_conditions_they_must(order):
    """Consistency (sum 1), symmetry, and the odd moments sum g^3, g^5, ... below the order
    vanish: necessary conditions of a symmetric composition of order ``order`` (Hairer,
    Lubich & Wanner V.3.2). A wrong digit in a published weight breaks them at its size."""
    g = np.array(stage_weights(order))
    assert g.size == {4: 3, 6: 9, 8: 17}[order]
    assert np.array_equal(g, g[::-1])
    assert abs(g.sum() - 1.0) < 4e-16
    for power in range(3, order, 2):
        assert abs(np.sum(g**power)) < 2e-15 * np.sum(np.abs(g) ** power), power


def test_the_triple_jump_steps_outside_its_step_and_kahan_li_does_not():
    earliest, latest = composition_reach(4)
    assert earliest == pytest.approx(-0.3512, abs=1e-4) and latest == pytest.approx(1.3512, abs=1e-4)
    for order in (6, 8):
        earliest, latest = composition_reach(order)
        assert 0.0 <= earliest and latest <= 1.0 + 1e-15


# dt from which each order is asymptotic on the body below (measured: the fits use 3-5 points)
LARGEST_DT = {4: 0.4, 6: 0.4, 8: 0.8}


@pytest.mark.parametrize("order", [4, 6, 8])
@pytest.mark.parametrize("name", ["splitting", "no_squish", "midpoint"])
def test_compositions_reach_their_order_on_a_free_asymmetric_body(name, order, asymmetric_scene):
    """Against the exact solution; measured 3.90-3.93, 5.94-5.97 and 7.90-8.24."""
    dts = LARGEST_DT[order] / 2.0 ** np.arange(5)
    runs = [simulate([asymmetric_scene], name, dt, 0.8, {"composition": order}) for dt in dts]
    reference = reference_solution(asymmetric_scene, runs[0].time)
    assert reference.name == "exact_asymmetric"
    errors = [orientation_error(r.quaternion[0, -1], reference.quaternion[-1]) for r in runs]
    assert abs(fitted(dts, errors) - order) <= ORDER_TOLERANCE, errors


LOADED_LONGER = {**LOADED, "duration": 3.2}  # output every 0.8 s


@pytest.mark.parametrize("order, largest", [(2, 0.08), (4, 0.4), (6, 0.4)])
def test_exact_split_under_loads_converges_at_its_order(order, largest):
    """Moments in body and space axes, a body-fixed force and gravity, against DOP853 (whose
    own error, ~1e-13, keeps order 8 from showing here: it shows on the free body above).
    Measured 2.00, 4.01, 5.99; exact_split's error is 13x below splitting's at order 2."""
    scene = scene_from_mapping(LOADED_LONGER, source="test")
    dts = largest / 2.0 ** np.arange(5)
    runs = [simulate([scene], "exact_split", dt, 0.8, {"composition": order}) for dt in dts]
    reference = dop853_reference(scene, runs[0].time)
    errors = [orientation_error(r.quaternion[0, -1], reference.quaternion[-1]) for r in runs]
    assert abs(fitted(dts, errors) - order) <= ORDER_TOLERANCE, errors
    travel = np.linalg.norm(reference.position[-1] - reference.position[0])
    position = [np.linalg.norm(r.position[0, -1] - reference.position[-1]) / travel for r in runs]
    # the centre of mass is a smooth, nearly polynomial path: DOP853 has it to ~1e-15
    assert abs(fitted(dts, position, floor=1e-13) - order) <= ORDER_TOLERANCE, position


def test_a_composition_takes_tabulated_loads_at_its_stage_times():
    """A space moment linear in time (one segment of a table reaching past both ends of the
    run): the triple jump keeps order 4 only if every stage takes the load at its own time,
    including those before the step's start. Measured 3.98."""
    table = [[-1.0, -0.09375, -0.0625, 0.03125], [4.2, 0.39375, 0.2625, -0.13125]]
    scene = scene_from_mapping({**LOADED_LONGER, "loads": {"moment_space": {"table": table}}}, source="test")
    dts = 0.4 / 2.0 ** np.arange(5)
    runs = [simulate([scene], "exact_split", dt, 0.8, {"composition": 4}) for dt in dts]
    # not the archive's reference: that is exact_split composed, the code under test
    reference = dop853_reference(scene, runs[0].time)
    errors = [orientation_error(r.quaternion[0, -1], reference.quaternion[-1]) for r in runs]
    assert abs(fitted(dts, errors) - 4) <= ORDER_TOLERANCE, errors


FREE_BODIES = {
    "largest axis": ([1.0, 2.0, 3.0], [0.6, 1.5, 0.9]),
    "smallest axis": ([1.0, 2.0, 3.0], [2.0, 0.3, 0.4]),
    "plate, unsorted": ([0.65, 1.0, 0.35], [1.5, 0.9, 0.6]),
    "near the separatrix": ([1.0, 2.0, 3.0], [1e-4, 1.0, 1e-4]),
}
ROTATION = [0.3, -0.2, 0.5]


@pytest.mark.parametrize("body", FREE_BODIES)
def test_exact_split_integrates_a_free_body_exactly_at_any_step(body):
    """dt = T, T/10, T/100 (T = 10 s) against the solution written in mpmath at 40 digits:
    <= 1e-13 rad and 1e-13 relative in w (measured 1e-15 to 3e-14)."""
    inertia, omega = FREE_BODIES[body]
    scene = scene_from_mapping(
        {
            "body": {"inertia": inertia},
            "initial": {"angular_velocity": {"body": omega}, "orientation": {"rotation_vector": ROTATION}},
            "duration": 10.0,
        },
        source="test",
    )
    q0 = reference_solution(scene, np.array([0.0])).quaternion[0]
    q_exact, w_exact = exact_state(inertia, q0, omega, 10.0)
    w_exact = np.array([float(v) for v in w_exact])
    for dt in (10.0, 1.0, 0.1):
        run = simulate([scene], "exact_split", dt, 10.0)
        assert run.results["n_steps"][0] == round(10.0 / dt)
        assert angle_between(q_exact, run.quaternion[0, -1]) <= 1e-13, dt
        assert omega_error(run.omega_body[0, -1], w_exact) <= 1e-13, dt


@pytest.mark.parametrize("name, order", [("splitting", 6), ("no_squish", 8), ("exact_split", 6)])
def test_a_high_order_composition_keeps_the_momentum_vector(name, order, asymmetric_scene):
    """Order 6 and 8 with |L| and L to round-off over 10,000 steps (9 or 17 stages each)."""
    scene = asymmetric_scene.with_changes(duration=300.0)
    run = simulate([scene], name, 0.03, 3.0, {"composition": order})
    assert run.results["status"][0] == 0
    assert run.results["max_momentum_magnitude_error"][0] < 1e-12
    inertia = np.array(scene.body.inertia)
    assert np.max(momentum_error(run.quaternion[0], run.omega_body[0], inertia)) < 1e-12


@pytest.mark.parametrize("value", [3, 10, "4", 4.5, True, None])
def test_a_bad_composition_is_refused_naming_the_orders(value):
    with pytest.raises(SchemeError) as error:
        get_scheme("splitting").option_row({"composition": value})
    assert "composition" in str(error.value) and "2, 4, 6, 8" in str(error.value)


def test_the_forecast_and_the_order_follow_the_composition():
    scheme = get_scheme("midpoint")
    assert scheme.nominal_order({}) == 2 and scheme.nominal_order({"composition": 6}) == 6
    assert scheme.seconds_per_step({"composition": 8}) == 17 * scheme.step_seconds
    assert get_scheme("rk4").seconds_per_step({}) == get_scheme("rk4").step_seconds
    # compensated sums cost 1.15-1.75 plain steps (docs/performance.md): the forecast takes
    # 1.5 of them, for each stage of a composition
    with_carry = scheme.seconds_per_step({"composition": 4, "compensated": 1})
    assert with_carry == pytest.approx(3 * 1.5 * scheme.step_seconds, rel=1e-15)


def test_a_swept_composition_is_archived_and_summarised_per_order(tmp_path):
    """nominal_order runs along (scheme, composition); the summary gives each composed
    scheme a row per order, fitted there alone, and rk4 (no such option) one row."""
    config = write_study(
        tmp_path,
        name="composed",
        sweep={
            "scheme": ["splitting", "rk4"],
            "run.options.composition": [2, 4, 6],
            "dt": {"halving": 0.4, "count": 4},
        },
        scene={
            "body": {"inertia": [1.0, 2.0, 3.0]},
            "initial": {"angular_velocity": {"body": [0.6, 1.5, 0.9]}},
            "duration": 4.0,
        },
        output={"interval": 0.8},
    )
    done = run_study(load_study(config), tmp_path / "out", quiet=True)
    ds = open_results(done.path)
    assert ds["nominal_order"].dims == ("scheme", "composition")
    assert ds["nominal_order"].sel(scheme="splitting").values.tolist() == [2, 4, 6]
    assert ds["nominal_order"].sel(scheme="rk4").values.tolist() == [4, 4, 4]
    rows = {row["scheme"]: row for row in scheme_rows(ds)}
    assert list(rows) == [
        "splitting, composition 2",
        "splitting, composition 4",
        "splitting, composition 6",
        "rk4",
    ]
    for row in rows.values():
        assert abs(row["order"][0] - row["nominal"]) <= ORDER_TOLERANCE, row


def test_the_triple_jump_under_tabulated_loads_is_warned_about(tmp_path):
    table = [[0.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 1.0]]
    config = write_study(
        tmp_path,
        name="jump",
        run={"scheme": "splitting", "dt": 0.01, "options": {"composition": 4}},
        scene={
            "body": {"inertia": [1.0, 2.0, 3.0]},
            "initial": {"angular_velocity": {"body": [0.6, 1.5, 0.9]}},
            "loads": {"moment_body": {"table": table}},
            "duration": 2.0,
        },
    )
    (warning,) = load_study(config).warnings
    assert "composition 4" in warning and "0.35 dt outside each step" in warning
    assert "use composition 6 or 8" in warning


# The plate of configs/long_run_convergence.yaml: about 160 wobble periods in 1000 s
PLATE = {
    "body": {"inertia": [0.35, 0.65, 1.0]},
    "initial": {"angular_velocity": {"body": [0.6, 1.5, 0.9]}, "orientation": {"rotation_vector": ROTATION}},
    "duration": 1000.0,
}
LONG_RUN_DTS = 0.02 / 2.0 ** np.arange(5)  # 0.02 .. 0.00125 s: 5e4 .. 8e5 steps


@pytest.fixture(scope="module")
def plate_at_the_end():
    """The plate's scene and its quaternion at 1000 s from the 40-digit solution."""
    scene = scene_from_mapping(PLATE, source="test")
    q0 = reference_solution(scene, np.array([0.0])).quaternion[0]
    q_exact, _ = exact_state(
        PLATE["body"]["inertia"], q0, PLATE["initial"]["angular_velocity"]["body"], PLATE["duration"]
    )
    return scene, q_exact


def long_run(scene, name, dts, options=None):
    """Final orientation errors (rad, against nothing yet) and largest energy errors."""
    runs = [simulate([scene], name, dt, PLATE["duration"], options or {}) for dt in dts]
    return runs, np.array([run.results["max_energy_error"][0] for run in runs])


@pytest.mark.parametrize("name", ["splitting", "no_squish"])
def test_a_symmetric_composition_keeps_its_order_over_a_long_run(name, plate_at_the_end):
    """1000 s, dt 0.02 .. 0.0025 s: the triple jump of a symplectic scheme keeps its energy
    error bounded, so its phase error grows as dt^4 t and the fit is 4 over all three steps
    (measured 4.00; the 0.00125 s step, 2.4e6 stages, is at its rounding, 6e-10 rad)."""
    scene, q_exact = plate_at_the_end
    dts = LONG_RUN_DTS[:4]
    runs, _ = long_run(scene, name, dts, {"composition": 4})
    errors = [angle_between(q_exact, run.quaternion[0, -1]) for run in runs]
    fit = asymptotic_order(dts, np.array(errors), floor=1e-11)
    assert fit.used.all(), errors
    assert abs(fit.order - 4.0) <= ORDER_TOLERANCE, errors


def test_rk4_over_a_long_run_is_not_yet_fourth_order_because_its_energy_drifts(plate_at_the_end):
    """Why configs/long_run_convergence.yaml fits rk4 above 4: its energy error falls as dt^5
    (measured slopes 5.00 down to 0.0025 s), the frequencies follow the energy, and the phase error dt^5 t^2
    that makes outgrows the scheme's own dt^4 t at 1000 s for every step above ~1e-3 s. The
    local slopes of the orientation error fall towards 4 (measured 4.80, 4.66, 4.48, 4.12);
    finer steps are at float64's rounding (3.6e-11 rad at 6.25e-4 s against a truncation
    error of ~5e-12), so no step shows the order 4 over three halvings."""
    scene, q_exact = plate_at_the_end
    runs, energy = long_run(scene, "rk4", LONG_RUN_DTS)
    errors = np.array([angle_between(q_exact, run.quaternion[0, -1]) for run in runs])
    logs = np.log(LONG_RUN_DTS)
    # the finest energy error, 1e-13 after 8e5 steps, is rounding
    energy_slopes = np.diff(np.log(energy[:4])) / np.diff(logs[:4])
    assert np.all(np.abs(energy_slopes - 5.0) <= 0.2), energy
    slopes = np.diff(np.log(errors)) / np.diff(logs)
    assert np.all(np.diff(slopes) < 0.0) and slopes[0] > 4.6 and 3.9 < slopes[-1] < 4.3, errors
