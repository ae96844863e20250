"""Bullet's bodies as schemes (rbstudy/engines/bullet.py): what each kind computes, told by
agreement with schemes written from their formulas, their order against the exact solution,
their energy over a long run, and the bounds Bullet puts on a step's turn."""

import numpy as np
import pytest
from engine_cases import compared_scenes, difference, example_scheme, make_scene, run
from helpers import final_orientation_errors
from scipy.spatial.transform import Rotation

pytest.importorskip("pybullet")

BULLET = ("bullet_multibody", "bullet_rigidbody")


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


def test_the_rigid_body_is_the_linearised_backward_euler_on_free_bodies():
    """btRigidBody's implicit gyroscopic step (one Newton step of backward Euler in the body
    frame, then the exponential turn with the new velocity) is the example plug-in's
    linearised backward Euler, to round-off on the free top and the asymmetric body. Under a
    moment they differ by O(h): Bullet adds the moment's impulse explicitly before the
    gyroscopic step, the example solves for both at once."""
    scenes = compared_scenes()
    example = example_scheme()
    coarse, fine = (
        [
            np.max(
                np.abs(
                    run("bullet_rigidbody", [body], dt, round(0.5 / dt))
                    - run(example, [body], dt, round(0.5 / dt))
                )
            )
            for body in scenes
        ]
        for dt in (0.01, 0.005)
    )
    assert max(coarse[:2]) < 1e-12
    assert coarse[2] > 1e-4
    assert np.log2(coarse[2] / fine[2]) == pytest.approx(1.0, abs=0.1)


def test_the_multibody_is_semi_implicit_euler_with_the_explicit_gyroscopic_term():
    """btMultiBody's step (accelerations at the old velocity, then the turn with the new)
    is MuJoCo's Euler to round-off, loads included, where MuJoCo is installed; against
    rbstudy's euler, which turns with the old velocity, the difference is O(h)."""
    scenes = compared_scenes()
    coarse, fine = (difference("bullet_multibody", "euler", scenes, dt) for dt in (0.01, 0.005))
    np.testing.assert_allclose(np.log2(coarse / fine), 1.0, atol=0.15)
    pytest.importorskip("mujoco")
    assert np.all(difference("bullet_multibody", "mujoco_euler", scenes, 0.01) < 1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", BULLET)
def test_each_is_of_order_one_on_an_asymmetric_body(scheme):
    errors = final_orientation_errors(_asymmetric(4.0), scheme, [0.01, 0.005, 0.0025], 0.04)
    np.testing.assert_allclose(np.log2(errors[:-1] / errors[1:]), 1.0, atol=0.05)


@pytest.mark.slow
def test_the_explicit_term_gains_energy_and_the_implicit_one_loses_it():
    """Over 20 s at dt = 0.01 s the multibody's energy grows (the failure of Bullet PR 346's
    explicit gyroscopic force) and the rigid body's decays, each by percents."""
    inertia = np.array([1.0, 2.0, 3.0])
    energy = {}
    for scheme in BULLET:
        w = run(scheme, [_asymmetric(20.0)], 0.01, 2000)[0][:, 10:13]
        energy[scheme] = 0.5 * (inertia * w * w).sum(axis=1)
    gain = energy["bullet_multibody"][-1] / energy["bullet_multibody"][0] - 1.0
    loss = energy["bullet_rigidbody"][-1] / energy["bullet_rigidbody"][0] - 1.0
    assert 0.01 < gain < 0.5
    assert -0.5 < loss < -0.01


def _bullet_turn(angle):
    """The turn of a Bullet step of angle ``angle`` = |w| dt past pi/4: its exponential map
    (btTransformUtil::integrateTransform, btMultiBody::stepPositionsMultiDof) lowers the rate
    to pi/4 / dt in the half-angle's sine but not in the scale of the axis, and normalises."""
    limit = np.pi / 4
    return 2.0 * np.arctan(angle * np.sin(limit / 2) / limit / np.cos(limit / 2))


@pytest.mark.parametrize("scheme", BULLET)
def test_a_step_of_more_than_an_eighth_of_a_turn_is_cut_short(scheme):
    """Bullet bounds a step's turn at pi/4 (ANGULAR_MOTION_THRESHOLD; pybullet does not
    expose it): a spin of 100 rad/s about a principal axis at dt = 0.01 s turns by 0.971 rad,
    not 1 rad, in a step, and keeps its rate; at 200 rad/s, by 1.62 rad, not 2."""
    dt = 0.01
    for rate in (100.0, 200.0):
        body = make_scene(
            body={"inertia": [1.0, 2.0, 3.0]},
            duration=dt,
            initial={"angular_velocity": {"body": [0.0, 0.0, rate]}},
        )
        after = run(scheme, [body], dt, 1)[0, 1]
        assert after[12] == pytest.approx(rate, rel=1e-12)
        turn = Rotation.from_quat(after[3:7]).magnitude()
        assert turn == pytest.approx(_bullet_turn(rate * dt), rel=1e-12)
        assert turn < rate * dt - 0.02
