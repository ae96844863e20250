"""Option `compensated`: compensated summation of the state updates (issue 33).

Compensated runs keep each scheme's order; over a long run of a free asymmetric body their
rounding follows Brouwer's law and ends far below that of plain sums; the increments of
rotations are accurate to their own size; the option is checked like any other."""

import math

import mpmath as mp
import numpy as np
import pytest
from helpers import ROUND_OFF_FLOOR, final_orientation_errors

from rbstudy.errors import SchemeError
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics.free_flow import free_flow_batch
from rbstudy.numerics.rotation import cos_minus_one, quat_cayley_minus_one, quat_exp_minus_one
from rbstudy.physics.metrics import asymptotic_order, orientation_error
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import BUILTIN, get_scheme, scheme_groups

COMPENSATED = [name for name, scheme in BUILTIN.items() if "compensated" in {o.name for o in scheme.options}]
ON = {"compensated": 1}
ORDER_TOLERANCE = 0.25
# Relative error allowed of an increment computed without cancellation: a few roundings.
INCREMENT_RTOL = 8 * np.finfo(float).eps
# The long run: Brouwer's exponents and the slack issue 33 allows them, and how far below
# the plain run's the compensated errors must end.
ENERGY_LAW, ANGLE_LAW, LAW_SLACK = 0.5, 1.5, 0.2
GAIN = 10.0


def test_every_builtin_scheme_offers_it():
    """rbstudy's own fixed-step schemes; the published steps are written as their sources
    give them, without it."""
    assert set(COMPENSATED) == set(scheme_groups()["builtin"])


# exact_split is exact at any step on the free body below: its order under loads is tested in
# tests/test_free_increment.py
@pytest.mark.parametrize("name", [name for name in COMPENSATED if name != "exact_split"])
def test_compensated_runs_keep_the_order(name, asymmetric_scene):
    dts = 0.04 / 2.0 ** np.arange(5)
    errors = final_orientation_errors(asymmetric_scene, name, dts, 0.04, ON)
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    assert used.sum() >= 3, errors
    assert abs(order - BUILTIN[name].order) <= ORDER_TOLERANCE, (order, errors)


def test_composed_compensated_steps_keep_the_composed_order(asymmetric_scene):
    """The stages of a composition share the carry."""
    dts = 0.2 / 2.0 ** np.arange(4)
    errors = final_orientation_errors(asymmetric_scene, "splitting", dts, 0.2, {"composition": 4, **ON})
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    assert used.sum() >= 3 and abs(order - 4) <= ORDER_TOLERANCE, (order, errors)


@pytest.mark.parametrize("name", COMPENSATED)
def test_compensated_batch_equals_case_by_case_bit_for_bit(name, abaqus_scene, asymmetric_scene):
    """The carry is per body: pairs of lanes (leapfrog) and batches keep each body's bits."""
    scenes = [abaqus_scene.with_changes(duration=0.5), asymmetric_scene.with_changes(duration=0.5)] * 2
    scenes.append(scenes[1])
    batch = simulate(scenes, name, 0.01, 0.1, ON)
    plain = simulate(scenes[:1], name, 0.01, 0.1)
    assert not np.array_equal(batch.quaternion[0], plain.quaternion[0])  # the option acts
    for i, scene in enumerate(scenes):
        alone = simulate([scene], name, 0.01, 0.1, ON)
        assert np.array_equal(batch.quaternion[i], alone.quaternion[0])
        assert np.array_equal(batch.omega_body[i], alone.omega_body[0])


def _growth(steps, errors):
    """Slope of log(running max |error|) against log(steps)."""
    envelope = np.maximum.accumulate(np.abs(errors))
    return np.polyfit(np.log(steps), np.log(envelope), 1)[0]


@pytest.mark.slow
def test_long_run_rounding_follows_brouwers_law():
    """2e5 steps of splitting composed to order 8 (its truncation is below the rounding
    here) on two free asymmetric bodies, against the exact motion: compensated, the energy
    grows no faster than n^(1/2) and the angle no faster than n^(3/2), each ending at least
    10x below the plain run's (pipelines/bench_round_off.py: the same over 1e8 steps)."""
    inertia = np.array([1.0, 2.0, 3.0])
    dt, steps = 0.02, 200_000
    scenes = [
        scene_from_mapping(
            {
                "body": {"inertia": inertia.tolist()},
                "initial": {
                    "angular_velocity": {"body": spin},
                    "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
                },
                "duration": steps * dt,
            },
            source="test",
        )
        for spin in ([0.6, 1.5, 0.9], [-1.1, 0.4, 0.7])
    ]
    interval = steps * dt / 200
    runs = {
        flag: simulate(scenes, "splitting", dt, interval, {"composition": 8, "compensated": flag})
        for flag in (0, 1)
    }
    time = runs[0].time
    states = np.array([scene.state_row() for scene in scenes])
    exact_q = np.empty((len(scenes), time.size, 4))
    exact_w = np.empty((len(scenes), time.size, 3))
    free_flow_batch(
        np.tile(inertia, (len(scenes), 1)),
        states[:, 3:7].copy(),
        states[:, 10:13].copy(),
        time,
        exact_q,
        exact_w,
    )
    energy0 = 0.5 * (inertia * exact_w[:, :1] ** 2).sum(-1)
    energy = {flag: 0.5 * (inertia * run.omega_body**2).sum(-1) / energy0 - 1.0 for flag, run in runs.items()}
    angle = {flag: orientation_error(run.quaternion, exact_q) for flag, run in runs.items()}
    later = time > 0
    n = time[later] / dt
    for b in range(len(scenes)):
        for errors, law in ((energy, ENERGY_LAW), (angle, ANGLE_LAW)):
            plain, compensated = errors[0][b, later], errors[1][b, later]
            assert _growth(n, compensated) <= law + LAW_SLACK, compensated
            assert np.max(np.abs(compensated[-20:])) * GAIN <= np.max(np.abs(plain[-20:])), (
                compensated[-1],
                plain[-1],
            )


def test_increments_of_rotations_are_accurate_to_their_own_size():
    """Against 40 digits, at angles down to 1e-9 rad where ``cos - 1`` written plainly
    loses every digit, and across the small-angle branch of `quat_exp_minus_one`."""
    mp.mp.dps = 40
    for angle in (1e-9, 3e-5, 1.5e-4, 1e-2, 0.7, 2.5):
        v = (0.6 * angle, -0.8 * angle, 0.0)
        half = mp.mpf(angle) / 2
        exact_cos = float(mp.cos(half) - 1)
        exact_sin = float(mp.sin(half) / angle)
        got = quat_exp_minus_one(v)
        assert abs(got[3] - exact_cos) <= INCREMENT_RTOL * abs(exact_cos), angle
        assert abs(got[0] - 0.6 * angle * exact_sin) <= INCREMENT_RTOL * abs(got[0]), angle
        assert abs(
            cos_minus_one(math.sin(angle), math.cos(angle)) - float(mp.cos(angle) - 1)
        ) <= INCREMENT_RTOL * abs(float(mp.cos(angle) - 1))
        a = mp.mpf(angle) ** 2 / 4
        exact_cayley = float(1 / mp.sqrt(1 + a) - 1)
        assert abs(quat_cayley_minus_one(v)[3] - exact_cayley) <= INCREMENT_RTOL * abs(exact_cayley), angle


@pytest.mark.parametrize("value", [0, 1, True, False, 1.0])
def test_the_option_takes_a_flag(value):
    rk4 = get_scheme("rk4")
    assert rk4.option_row({"compensated": value})[rk4.slots["compensated"]] == float(value)


@pytest.mark.parametrize("value", [2, 0.5, "yes", None])
def test_the_option_refuses_anything_else(value):
    with pytest.raises(SchemeError, match=r"option 'compensated': got .*; expected 0 or 1 \(false or true\)"):
        get_scheme("rk4").option_row({"compensated": value})
