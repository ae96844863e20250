"""Rapier (rbstudy/engines/rapier.py) against the formula of its sources, and its float32
floor. The conventions (at rest, constant spins, batch = solo) are in tests/test_engines.py."""

import numpy as np
import pytest
from engine_cases import make_scene, run
from helpers import final_orientation_errors
from scipy.spatial.transform import Rotation

from rbstudy.numerics import state as S
from rbstudy.physics.metrics import asymptotic_order
from rbstudy.schemes import unavailable_schemes

if "rapier" in unavailable_schemes():
    pytest.skip(unavailable_schemes()["rapier"].reason, allow_module_level=True)

INERTIA = np.array([1.0, 2.0, 3.0])


def asymmetric(spin=(0.6, 1.5, 0.9), duration=4.0):
    return make_scene(
        body={"inertia": INERTIA.tolist()},
        initial={
            "angular_velocity": {"body": list(spin)},
            "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
        },
        duration=duration,
    )


def cayley(v):
    """The Cayley map's rotation of ``v``: the quaternion ``(v / 2, 1)`` normalised."""
    return Rotation.from_quat([*(0.5 * v), 1.0])


def rapier_formula(spin, dt, n_steps, substeps=4, turn=cayley):
    """Rapier's step as its sources give it, in float64: ``substeps`` times Jolt's gyroscopic
    update of the body momentum (an Euler step scaled back to |m|) and a turn of the frame by
    ``turn(d w)`` (the Cayley map; `Rotation.from_rotvec`: the exponential), ``d = dt /
    substeps``."""
    q, w, d = Rotation.from_rotvec([0.3, -0.2, 0.5]), np.array(spin, dtype=float), dt / substeps
    for _ in range(n_steps * substeps):
        m = INERTIA * w
        stepped = m + d * np.cross(m, w)
        w = stepped * np.linalg.norm(m) / np.linalg.norm(stepped) / INERTIA
        q = q * turn(d * w)
    return q


def test_rapier_is_four_substeps_of_jolts_update_with_a_cayley_turn():
    """On a fast asymmetric body (h |w| = 0.36), 50 steps: Rapier's frame is the formula's to
    float32's rounding (1.1e-5 rad measured), and over 100 times further from the same
    formula with the exponential turn (Jolt's: 1.5e-2), or with one substep a step (1.6)."""
    spin, dt, n_steps = (6.0, 15.0, 9.0), 0.02, 50
    samples = run("rapier", [asymmetric(spin, dt * n_steps)], dt, n_steps)[0]
    reached = Rotation.from_quat(samples[-1, S.QUATERNION : S.QUATERNION + 4])
    gap = (rapier_formula(spin, dt, n_steps).inv() * reached).magnitude()
    assert gap < 5e-5
    with_exp = (rapier_formula(spin, dt, n_steps, turn=Rotation.from_rotvec).inv() * reached).magnitude()
    one_substep = (rapier_formula(spin, dt, n_steps, substeps=1).inv() * reached).magnitude()
    assert min(with_exp, one_substep) > 100 * gap, (gap, with_exp, one_substep)


def test_float32_sets_rapiers_floor():
    """I = (1, 2, 3) over 4 s: first order from dt = 0.04 s to 0.01 s (errors 2.5e-2 to
    6.5e-3), then float32's rounding of each step takes over: the error grows as the step
    shrinks (4.6e-3 at 1.25e-3 s, 1.1e-2 at 6.25e-4 s, 26 times what first order from 0.04 s
    foretells there)."""
    dts = 0.04 / 2.0 ** np.arange(7)
    errors = final_orientation_errors(asymmetric(), "rapier", dts, 0.04)
    order, used, _ = asymptotic_order(dts[:3], errors[:3], floor=1e-13)
    assert abs(order - 1.0) < 0.1 and used.sum() == 3, errors
    assert errors[-1] > 2.0 * errors[-3], errors  # finer, and worse
    assert errors[-1] > 10.0 * errors[0] * dts[-1] / dts[0], errors


def test_without_gyroscopic_forces_the_spin_is_held_in_the_world():
    """Option gyroscopic 0: the world spin stays what it was (to float32), so a tumbling body
    keeps a wrong axis and its error does not fall with the step (2.11 rad at 4 s)."""
    scene = asymmetric()
    samples = run_with_options(scene, {"gyroscopic": 0}, 0.01, 40)
    q = samples[:, S.QUATERNION : S.QUATERNION + 4]
    world = Rotation.from_quat(q).apply(samples[:, S.OMEGA : S.OMEGA + 3])
    np.testing.assert_allclose(world, np.tile(world[0], (len(world), 1)), atol=1e-6)
    errors = final_orientation_errors(scene, "rapier", [0.04, 0.01], 0.04, {"gyroscopic": 0})
    assert np.all(errors > 2.0), errors


def run_with_options(scene, options, dt, n_steps):
    """Every step of ``scene`` under rapier with ``options``: samples (n_steps + 1, N_STATE)."""
    from rbstudy.numerics.driver import run_batch
    from rbstudy.physics.scenes import param_rows
    from rbstudy.schemes import get_scheme

    scheme = get_scheme("rapier")
    return run_batch(
        scheme,
        np.array([scene.state_row()]),
        param_rows([scene]),
        scheme.option_row(options)[None, :],
        dt,
        n_steps,
        1,
    ).samples[0]
