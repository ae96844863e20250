"""The exact free flow as an increment (`rbstudy.numerics.free_increment`), and `exact_split`
with compensated sums, which the integrated references run: the increment is the flow, to its
own size; compensated, the composition keeps its order under loads and ends a long run far
closer to the exact motion (free body) and to an extended-precision solution (loaded body)
than with plain sums."""

import numpy as np
import pytest
from extended_oracle import loaded_rotation
from helpers import LOADED

from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics.dynamics import to_momentum
from rbstudy.numerics.free_flow import free_body, free_flow_batch, free_motion
from rbstudy.numerics.free_increment import free_increment
from rbstudy.numerics.rotation import quat_mul
from rbstudy.physics import references
from rbstudy.physics.metrics import asymptotic_order, orientation_error
from rbstudy.physics.references import dop853_reference, reference_solution
from rbstudy.physics.simulate import simulate

ON = {"compensated": 1}
# q + dq against free_motion's state, which is itself good to a few ulps of the state
FLOW_ATOL = 2e-14
# How far below the plain sums' error the compensated one must end.
GAIN = 10.0
TUMBLING = {
    "body": {"inertia": [1.0, 2.0, 3.0]},
    "initial": {
        "angular_velocity": {"body": [0.6, 1.5, 0.9]},
        "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
    },
}


def random_bodies(count, seed):
    """(inertia, omega, unit q) of ``count`` bodies, from moderate shapes to inertias within
    1% of each other (the characteristic n of the third integral down to ~-1e3)."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        spread = 0.01 if k % 3 == 0 else 1.0
        inertia = 1.0 + spread * rng.uniform(0.0, 1.0, 3)
        q = rng.normal(size=4)
        yield tuple(inertia), tuple(2.0 * rng.normal(size=3)), tuple(q / np.linalg.norm(q))


def same_rotation_distance(a, b):
    """Largest component difference of two quaternions, up to sign."""
    a, b = np.asarray(a), np.asarray(b)
    return min(np.abs(a - b).max(), np.abs(a + b).max())


def test_the_increment_is_the_exact_flow():
    """Steps from 1e-4 s to several quarter periods of the wobble (past one, the increment is
    the difference of free_motion's states)."""
    for inertia, omega, q in random_bodies(300, seed=3):
        for h in (1e-4, 0.03, 0.4, 3.0):
            body = free_body(inertia, omega)
            q_h, w_h = free_motion(body, q, h)
            dq, dw = free_increment(body, q, h)
            assert same_rotation_distance(np.add(q, dq), q_h) <= FLOW_ATOL, (inertia, omega, h)
            assert np.abs(np.add(omega, dw) - w_h).max() <= FLOW_ATOL * np.linalg.norm(omega)


def test_the_increment_is_accurate_to_its_own_size():
    """Over 1e-9 s the increments are Euler's equations times h, to a relative h: a difference
    of two states would be off by an ulp of the state, 1e-7 of the increment."""
    h = 1e-9
    for inertia, omega, q in random_bodies(30, seed=5):
        dq, dw = free_increment(free_body(inertia, omega), q, h)
        m = to_momentum(omega, inertia)
        euler = h * np.cross(m, omega) / np.array(inertia)
        turn = 0.5 * h * np.array(quat_mul(q, (*omega, 0.0)))
        assert np.abs(np.array(dw) - euler).max() <= 1e-8 * np.abs(euler).max()
        assert np.abs(np.array(dq) - turn).max() <= 1e-8 * np.abs(turn).max()


@pytest.mark.parametrize("order, largest", [(2, 0.08), (4, 0.4), (6, 0.4)])
def test_compensated_exact_split_converges_at_its_order_under_loads(order, largest):
    """Every kind of constant load, against DOP853 (as tests/test_compositions.py does for
    the plain step)."""
    scene = scene_from_mapping({**LOADED, "duration": 3.2}, source="test")
    dts = largest / 2.0 ** np.arange(5)
    runs = [simulate([scene], "exact_split", dt, 0.8, {"composition": order, **ON}) for dt in dts]
    reference = dop853_reference(scene, runs[0].time)
    errors = [orientation_error(r.quaternion[0, -1], reference.quaternion[-1]) for r in runs]
    fitted, used, _ = asymptotic_order(dts, np.array(errors), floor=1e-12)
    assert used.sum() >= 3 and abs(fitted - order) <= 0.25, errors


@pytest.mark.slow
def test_over_a_long_free_run_compensated_exact_split_ends_far_closer(asymmetric_scene):
    """2e4 steps of the order-8 composition (3.4e5 exact stages) of a free asymmetric body,
    against its exact motion: each stage of the plain one rounds to an ulp of the state."""
    scene = asymmetric_scene.with_changes(duration=400.0)
    runs = {
        flag: simulate([scene], "exact_split", 0.02, 400.0, {"composition": 8, "compensated": flag})
        for flag in (0, 1)
    }
    exact_q, exact_w = np.empty((1, 1, 4)), np.empty((1, 1, 3))
    free_flow_batch(
        np.array([scene.body.inertia]),
        np.array([scene.quaternion]),
        np.array([scene.omega_body]),
        np.array([400.0]),
        exact_q,
        exact_w,
    )
    error = {flag: orientation_error(run.quaternion[0, -1], exact_q[0, 0]) for flag, run in runs.items()}
    assert GAIN * error[1] <= error[0], error


@pytest.mark.slow
def test_the_compensated_reference_is_far_closer_to_an_extended_precision_solution(monkeypatch):
    """A body moment spins the body up fivefold over 10 s, through the separatrix: the plain
    composition at the same steps rounds to ~7e-12 rad, the compensated reference to far
    less, against a solution in 80-bit floats."""
    scene = scene_from_mapping(
        {**TUMBLING, "duration": 10.0, "loads": {"moment_body": [0.0, 0.0, 3.0]}}, source="test"
    )
    times = np.arange(11) * 1.0
    exact = loaded_rotation(
        scene.body.inertia, scene.quaternion, scene.omega_body, 10.0, 0.005, moment_body=(0.0, 0.0, 3.0)
    )[0]
    compensated = reference_solution(scene, times)
    assert compensated.name == "exact_split_composition"
    monkeypatch.setattr(references, "REFERENCE_OPTIONS", {"composition": 8})
    plain = reference_solution(scene, times)
    errors = [orientation_error(r.quaternion[-1], exact) for r in (compensated, plain)]
    assert GAIN * errors[0] <= errors[1], errors
