"""Drake's integrators as schemes (rbstudy/engines/drake.py): the turn each gives a step of a
constant spin (its quaternion integrated as an ODE), its order against the exact solution,
its energy over a long run, the discrete plant against the semi-implicit Euler of the other
engines, and the discrete solvers' agreement on a free body."""

import numpy as np
import pytest
from engine_cases import compared_scenes, difference, make_scene, run, swept_errors
from helpers import final_orientation_errors
from scipy.spatial.transform import Rotation

from rbstudy.physics.simulate import simulate

pytest.importorskip("pydrake")

from rbstudy.engines import drake  # noqa: E402 (Drake's bindings are there: checked above)

DRAKE = ("drake_rk2", "drake_rk3", "drake_implicit_euler", "drake_discrete")
# The implicit Euler's Newton iterations stop at Drake's default tolerance, not at round-off:
# 1.2e-4 of the turn at |w| dt = 0.5 (set_target_accuracy(1e-10) gives the formula to 1e-16);
# the turn of one backward Euler step of dt would be 1.5% off.
_TURN_TOLERANCE = {"drake_implicit_euler": 5e-4}


def _asymmetric(duration):
    """I = (1, 2, 3) tumbling about no principal axis (tests/conftest.py's asymmetric body)."""
    return make_scene(
        body={"inertia": [1.0, 2.0, 3.0]},
        duration=duration,
        initial={
            "angular_velocity": {"body": [0.6, 1.5, 0.9]},
            "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
        },
    )


def _turn(scheme, angle):
    """The turn of one step of a spin about a principal axis, ``angle`` = |w| dt: each
    scheme's update of ``dq/dt = q (0, w)/2`` with ``w`` constant multiplies q by a quaternion
    (c, s axis), which Drake's kinematics normalise: the turn is 2 atan2(s, c).
    RK2 and RK3 truncate the exponential's series after the 2nd and 3rd powers; the discrete
    plant adds dt N(q) v (1, half); Drake's implicit Euler takes two backward Euler steps of
    dt/2, its pair for the error estimate, each dividing by (1 - (0, w) dt/4)."""
    half, quarter = angle / 2, angle / 4
    c, s = {
        "drake_rk2": (1 - half**2 / 2, half),
        "drake_rk3": (1 - half**2 / 2, half - half**3 / 6),
        "drake_implicit_euler": (1 - quarter**2, 2 * quarter),
        "drake_discrete": (1.0, half),
    }[scheme]
    return 2 * np.arctan2(s, c)


@pytest.mark.parametrize("scheme", DRAKE)
def test_a_step_of_a_constant_spin_turns_by_the_schemes_own_polynomial(scheme):
    """Not the exponential map: at |w| dt = 0.5 rad a step turns by 0.5051 (RK2), 0.50006
    (RK3), 0.4975 (implicit Euler), 0.4900 (discrete); the rate is kept to round-off."""
    dt = 0.01
    for rate in (2.5, 50.0):
        body = make_scene(
            body={"inertia": [1.0, 2.0, 3.0]},
            duration=dt,
            initial={"angular_velocity": {"body": [0.0, rate, 0.0]}},
        )
        after = run(scheme, [body], dt, 1)[0, 1]
        assert after[11] == pytest.approx(rate, rel=1e-13)
        turn = Rotation.from_quat(after[3:7]).magnitude()
        tolerance = _TURN_TOLERANCE.get(scheme, 1e-12)
        assert turn == pytest.approx(_turn(scheme, rate * dt), rel=tolerance)
    assert abs(turn - rate * dt) > 1e-5


@pytest.mark.slow
@pytest.mark.parametrize(
    "scheme, order", [("drake_rk2", 2), ("drake_rk3", 3), ("drake_implicit_euler", 1), ("drake_discrete", 1)]
)
def test_each_shows_its_order_on_an_asymmetric_body(scheme, order):
    errors = final_orientation_errors(_asymmetric(4.0), scheme, [0.01, 0.005, 0.0025], 0.04)
    np.testing.assert_allclose(np.log2(errors[:-1] / errors[1:]), order, atol=0.15)


@pytest.mark.slow
def test_energy_over_a_long_run():
    """Over 20 s at dt = 0.01 s: the explicit gyroscopic force of the discrete plant gains
    energy by percents (as Bullet's multibody does), and so does the implicit Euler, whose
    backward step is taken in the world frame with the quaternion's norm shrinking; the
    Runge-Kutta schemes keep it to 1e-4."""
    inertia = np.array([1.0, 2.0, 3.0])
    drift = {}
    for scheme in DRAKE:
        w = run(scheme, [_asymmetric(20.0)], 0.01, 2000)[0][:, 10:13]
        energy = 0.5 * (inertia * w * w).sum(axis=1)
        drift[scheme] = energy[-1] / energy[0] - 1.0
    assert 0.01 < drift["drake_discrete"] < 0.5
    assert 0.01 < drift["drake_implicit_euler"] < 0.5
    assert abs(drift["drake_rk2"]) < 1e-4
    assert abs(drift["drake_rk3"]) < 1e-4


@pytest.mark.slow
def test_the_discrete_plant_is_semi_implicit_euler_but_for_its_turn():
    """The discrete plant takes the velocity by the forces at the step's start, then turns
    with the new velocity, as MuJoCo's Euler and Bullet's multibody do (loads included); it
    turns by 2 atan(|w| dt / 2), not |w| dt, so the two differ by O(h^2), not by round-off.
    Against rbstudy's euler, which turns with the old velocity, the difference is O(h) under
    loads."""
    scenes = compared_scenes()
    coarse, fine = (difference("drake_discrete", "euler", scenes, dt) for dt in (0.01, 0.005))
    assert np.log2(coarse[2] / fine[2]) == pytest.approx(1.0, abs=0.1)
    pytest.importorskip("mujoco")
    coarse, fine = (difference("drake_discrete", "mujoco_euler", scenes, dt) for dt in (0.01, 0.005))
    np.testing.assert_allclose(np.log2(coarse / fine), 2.0, atol=0.05)


def test_tamsi_and_sap_step_a_free_body_alike(monkeypatch):
    """Without contact both discrete solvers return the free motion: the same numbers, to
    round-off (6e-15 after 50 steps)."""
    scenes = compared_scenes()
    sap = run("drake_discrete", scenes, 0.01, 50)
    monkeypatch.setattr(drake, "_DISCRETE_MODEL", drake.DiscreteContactApproximation.kTamsi)
    monkeypatch.setattr(drake, "_LOCAL", type(drake._LOCAL)())  # plants built again
    tamsi = run("drake_discrete", scenes, 0.01, 50)
    assert drake._plant(None, 0.01).plant.get_discrete_contact_solver().name == "kTamsi"
    np.testing.assert_allclose(tamsi, sap, rtol=0, atol=1e-13)


@pytest.mark.slow
def test_drake_schemes_sweep_into_the_archive(tmp_path):
    """Through the pipeline like any scheme, on the asymmetric top: statuses, Drake's version
    in the archive, and the orders from the archived errors."""
    errors = swept_errors(
        tmp_path, ["drake_rk3", "drake_discrete"], f"rbstudy's adapter of Drake {drake.VERSION}"
    )
    for scheme, order in (("drake_rk3", 3), ("drake_discrete", 1)):
        e = errors.sel(scheme=scheme).values  # dt ascending: the finest first
        assert abs(np.log2(e[1] / e[0]) - order) < 0.2, scheme


@pytest.mark.parametrize("scheme", ("drake_rk2", "drake_rk3"))
def test_a_stress_body_beyond_the_triangle_inequality_is_integrated_not_failed(scheme):
    """Hairer, Lubich and Wanner's I = (2, 1, 2/3) (`allow_unphysical`): Drake's spatial inertia
    refuses it unless its validity check is skipped, which the adapter does, so that every body
    finishes (it was stopped at its first step and reported as an implicit solver's failure)
    and follows rbstudy's rk4 to the scheme's order: halving dt divides the difference by
    2^order."""
    scene = make_scene(
        body={"inertia": [2.0, 1.0, 2.0 / 3.0], "allow_unphysical": True},
        duration=1.0,
        initial={"angular_velocity": {"body": [0.2268, 0.0, 1.3370]}},
    )
    gaps = []
    for dt in (0.02, 0.01):
        out = simulate([scene], scheme, dt, 0.1).output
        assert out.results["status"].tolist() == [0]
        exact = simulate([scene], "rk4", dt / 8, 0.1).output.samples
        gaps.append(np.max(np.abs(out.samples - exact)))
    order = {"drake_rk2": 2, "drake_rk3": 3}[scheme]
    assert np.log2(gaps[0] / gaps[1]) == pytest.approx(order, abs=0.3)
