"""The Abaqus force-free symmetric-top benchmark (docs/theory.md s2), integrated with hht alpha = 0.

What the benchmark shows and what we assert: w3 constant; the global w_x-w_y trace is a circle
of diameter 2 W sin(theta0) = 0.2499 ~ A; the motion seen in space has period
2 pi I1 / |L| = 0.4999 s; the body-frame precession frequency W = 2 pi (Abaqus reports 6.268).
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbstudy.physics.analytic import precession_frequency_exact
from rbstudy.physics.metrics import phase_rate
from rbstudy.physics.simulate import simulate

A, OMEGA3 = 0.25, 2.0 * math.pi
THETA0 = math.atan(A / (2.0 * OMEGA3))  # tan(theta0) = I1 A / (I3 w3)


@pytest.fixture(scope="module")
def run(abaqus_config, abaqus_scene):
    spec = abaqus_config["run"]
    return simulate(
        [abaqus_scene], spec["scheme"], spec["dt"], abaqus_config["output"]["interval"], spec["options"]
    )


def space_omega(run):
    rotation = Rotation.from_quat(run.quaternion[0])
    return rotation.apply(run.omega_body[0])


def test_bundled_config_is_the_benchmark(abaqus_config, abaqus_scene):
    assert abaqus_config["run"] == {"scheme": "hht", "options": {"alpha": 0.0}, "dt": 0.01}
    assert abaqus_scene.body.inertia == (1.0, 1.0, 2.0)
    assert abaqus_scene.duration == 2.0
    assert abaqus_scene.node_names == ("2", "3", "4")
    assert np.allclose(abaqus_scene.nodes, np.eye(3))


def test_initial_condition_is_the_benchmark_one(abaqus_scene):
    angles = Rotation.from_quat(abaqus_scene.quaternion).as_euler("ZXZ", degrees=True)
    assert np.allclose(angles, [0.0, math.degrees(THETA0), 90.0], atol=1e-12)
    assert math.isclose(math.degrees(THETA0), 1.1397, abs_tol=1e-4)
    omega0 = Rotation.from_quat(abaqus_scene.quaternion).apply(abaqus_scene.omega_body)
    assert np.allclose(omega0, [0.0, 0.12498, 6.28691], atol=1e-5)


def test_hht_runs_200_increments_with_one_newton_iteration_each(run):
    assert run.results["status"][0] == 0
    assert run.results["n_steps"][0] == 200
    assert run.results["iterations"][0] == 200  # Abaqus: "each increment requiring only 1 iteration"


def test_w3_constant(run):
    assert np.max(np.abs(run.omega_body[0, :, 2] - OMEGA3)) < 1e-12


def test_global_wx_wy_is_a_circle_of_diameter_a(run):
    omega = space_omega(run)
    radius = np.hypot(omega[:, 0], omega[:, 1])
    expected = 2.0 * OMEGA3 * math.sin(THETA0)  # 0.2499
    assert math.isclose(expected, 0.2499, abs_tol=1e-4)
    diameter = 2.0 * radius.mean()
    assert abs(diameter - expected) <= 0.01 * expected
    assert np.ptp(radius) <= 0.01 * radius.mean()  # a circle, not a spiral


def test_global_period_is_half_a_second(run):
    omega = space_omega(run)
    rate = phase_rate(omega[:, 0], omega[:, 1], run.time)
    period = 2.0 * math.pi / rate
    expected = 2.0 * math.pi * 1.0 / math.hypot(A, 2.0 * OMEGA3)  # 2 pi I1 / |L| = 0.4999
    assert math.isclose(expected, 0.4999, abs_tol=1e-4)
    assert abs(period - expected) <= 0.01 * expected


def test_precession_frequency_reported(run, abaqus_scene):
    measured = phase_rate(run.omega_body[0, :, 0], run.omega_body[0, :, 1], run.time)
    exact = precession_frequency_exact(abaqus_scene)
    assert math.isclose(exact, 2.0 * math.pi)
    # trapezoidal Newmark has a phase error of O((W h)^2 / 12): a fraction of a percent here
    assert abs(measured - exact) / exact < 2e-3
    print(
        f"\nhht alpha=0, dt=0.01: precession frequency {measured:.4f} rad/s, exact "
        f"{exact:.4f}, error {measured - exact:+.2e} (Abaqus reports 6.268)"
    )
