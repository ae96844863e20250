"""The closed forms against scipy's DOP853 at 1e-13, on random bodies and initial data."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbstudy.analytic import axial_moment, reference_solution, symmetric_top
from rbstudy.metrics import omega_error, orientation_error
from rbstudy.scenes import Body, Loads, Scene
from rbstudy.simulate import simulate

RNG = np.random.default_rng(2026)


def random_symmetric_scene(axis):
    transverse, axial = RNG.uniform(0.5, 2.0), RNG.uniform(0.05, 2.0)
    inertia = [transverse] * 3
    inertia[axis] = min(axial, 2 * transverse)
    return Scene(body=Body(mass=1.0, inertia=tuple(inertia)),
                 quaternion=tuple(Rotation.random(random_state=RNG).as_quat()),
                 omega_body=tuple(RNG.normal(scale=2.0, size=3)), duration=5.0)


@pytest.mark.parametrize("seed", range(6))
def test_symmetric_top_matches_dop853(seed):
    scene = random_symmetric_scene(axis=seed % 3)
    numeric = simulate([scene], "dop853", 0.05, 0.05)
    quaternion, omega = symmetric_top(scene.body.inertia, scene.quaternion, scene.omega_body,
                                      numeric.time)
    assert np.max(orientation_error(numeric.quaternion[0], quaternion)) < 1e-10
    assert np.max(omega_error(numeric.omega_body[0], omega)) < 1e-10


def test_axial_moment_matches_dop853():
    scene = Scene(body=Body(mass=1.0, inertia=(1.0, 1.5, 2.0)),
                  quaternion=tuple(Rotation.random(random_state=RNG).as_quat()),
                  omega_body=(0.0, 0.0, 2.0), loads=Loads(moment_body=(0.0, 0.0, -0.3)),
                  duration=3.0)
    numeric = simulate([scene], "dop853", 0.1, 0.1)
    quaternion, omega = axial_moment(scene.body.inertia, scene.quaternion, scene.omega_body,
                                     scene.loads.moment_body, numeric.time)
    assert np.max(orientation_error(numeric.quaternion[0], quaternion)) < 1e-10
    assert np.allclose(numeric.omega_body[0], omega, atol=1e-10)


def test_reference_records_which_solution_was_used():
    symmetric = random_symmetric_scene(axis=2)
    times = np.linspace(0.0, 1.0, 11)
    assert reference_solution(symmetric, times).name == "symmetric_top"
    asymmetric = symmetric.with_changes(body=Body(mass=1.0, inertia=(1.0, 2.0, 3.0)),
                                        duration=1.0)
    fallback = reference_solution(asymmetric, times)
    assert fallback.name == "dop853" and not fallback.exact
    pushed = symmetric.with_changes(loads=Loads(force_body=(1.0, 0.0, 0.0)), duration=1.0)
    assert reference_solution(pushed, times).name == "dop853"
