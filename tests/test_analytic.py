"""The closed forms against scipy's DOP853 at 1e-13, on random bodies and initial data."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbstudy.physics.analytic import (
    axial_moment,
    flip_interval_exact,
    symmetric_top,
    symmetry_axes,
    symmetry_axis,
)
from rbstudy.physics.metrics import omega_error, orientation_error, sign_change_interval
from rbstudy.physics.references import reference_solution, reference_solutions
from rbstudy.physics.scenes import Body, Loads, Scene
from rbstudy.physics.simulate import simulate

RNG = np.random.default_rng(2026)


def random_symmetric_scene(axis):
    transverse, axial = RNG.uniform(0.5, 2.0), RNG.uniform(0.05, 2.0)
    inertia = [transverse] * 3
    inertia[axis] = min(axial, 2 * transverse)
    return Scene(
        body=Body(mass=1.0, inertia=tuple(inertia)),
        quaternion=tuple(Rotation.random(random_state=RNG).as_quat()),
        omega_body=tuple(RNG.normal(scale=2.0, size=3)),
        duration=5.0,
    )


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_symmetric_top_matches_dop853(seed):
    scene = random_symmetric_scene(axis=seed % 3)
    numeric = simulate([scene], "dop853", 0.05, 0.05)
    quaternion, omega = symmetric_top(scene.body.inertia, scene.quaternion, scene.omega_body, numeric.time)
    assert np.max(orientation_error(numeric.quaternion[0], quaternion)) < 1e-10
    assert np.max(omega_error(numeric.omega_body[0], omega)) < 1e-10


def test_axial_moment_matches_dop853():
    scene = Scene(
        body=Body(mass=1.0, inertia=(1.0, 1.5, 2.0)),
        quaternion=tuple(Rotation.random(random_state=RNG).as_quat()),
        omega_body=(0.0, 0.0, 2.0),
        loads=Loads(moment_body=(0.0, 0.0, -0.3)),
        duration=3.0,
    )
    numeric = simulate([scene], "dop853", 0.1, 0.1)
    quaternion, omega = axial_moment(
        scene.body.inertia, scene.quaternion, scene.omega_body, scene.loads.moment_body, numeric.time
    )
    assert np.max(orientation_error(numeric.quaternion[0], quaternion)) < 1e-10
    assert np.allclose(numeric.omega_body[0], omega, atol=1e-10)


@pytest.mark.slow
def test_reference_records_which_solution_was_used():
    symmetric = random_symmetric_scene(axis=2)
    times = np.linspace(0.0, 1.0, 11)
    assert reference_solution(symmetric, times).name == "symmetric_top"
    asymmetric = symmetric.with_changes(body=Body(mass=1.0, inertia=(1.0, 2.0, 3.0)), duration=1.0)
    assert reference_solution(asymmetric, times).name == "exact_asymmetric"
    turned = asymmetric.with_changes(loads=Loads(moment_space=(0.0, 0.1, 0.0)))
    fallback = reference_solution(turned, times)
    assert fallback.name == "exact_split_composition" and np.all(np.isfinite(fallback.quaternion))
    pushed = symmetric.with_changes(loads=Loads(force_body=(1.0, 0.0, 0.0)), duration=1.0)
    assert reference_solution(pushed, times).name == "exact_split_composition"


def test_references_of_a_batch_equal_those_of_each_scene():
    scenes = [random_symmetric_scene(axis=k % 3) for k in range(6)]
    scenes.append(
        Scene(
            body=Body(mass=1.0, inertia=(1.0, 2.0, 3.0)),
            quaternion=(0.0, 0.0, 0.0, 1.0),
            omega_body=(0.3, 1.0, 0.2),
            duration=1.0,
        )
    )
    times = np.arange(11) * 0.1
    together = reference_solutions(scenes, times)
    assert [r.name for r in together] == ["symmetric_top"] * 6 + ["exact_asymmetric"]
    for scene, batch in zip(scenes, together, strict=True):
        alone = reference_solution(scene, times)
        assert np.max(orientation_error(batch.quaternion, alone.quaternion)) < 1e-14
        assert np.allclose(batch.omega_body, alone.omega_body, rtol=0, atol=1e-14)


@pytest.mark.parametrize(
    "inertia, omega",
    [
        ((1.0, 2.0, 3.0), (1e-3, 1.0, 1e-3)),  # the Dzhanibekov flip, ~27.5 s (docs/theory.md s3)
        ((1.0, 2.0, 3.0), (1.0, 0.2, 0.1)),  # circulating about the minimum axis
        ((3.0, 1.0, 2.0), (0.2, 0.5, 1.3)),  # axes not sorted
    ],
)
def test_flip_interval_matches_the_sign_changes_of_dop853(inertia, omega):
    scene = Scene(
        body=Body(mass=1.0, inertia=inertia),
        quaternion=(0.0, 0.0, 0.0, 1.0),
        omega_body=omega,
        duration=120.0,
    )
    numeric = simulate([scene], "dop853", 0.01, 0.01)
    middle = int(np.argsort(inertia)[1])
    measured = sign_change_interval(numeric.omega_body[0, :, middle], numeric.time)
    assert abs(measured / flip_interval_exact(scene) - 1.0) < 1e-8


def test_no_flip_interval_for_a_steady_spin_or_a_symmetric_body():
    spin = Scene(
        body=Body(mass=1.0, inertia=(1.0, 2.0, 3.0)),
        quaternion=(0.0, 0.0, 0.0, 1.0),
        omega_body=(0.0, 0.0, 1.0),
    )
    assert np.isnan(flip_interval_exact(spin))
    assert flip_interval_exact(spin.with_changes(body=Body(1.0, (1.0, 1.0, 2.0)))) is None


def test_one_body_and_many_bodies_get_the_same_symmetry_axis():
    """The symmetry rule is evaluated on three floats for one body (a sweep asks it of every
    case) and with numpy for many: the same answer, also at the tolerance's edge."""
    rng = np.random.default_rng(7)
    base = rng.uniform(0.5, 2.0, size=(2000, 3))
    edge = 1.0 + np.array([0.0, 0.5e-12, 1.0e-12, 1.5e-12, 3e-12])  # at the edge of 1e-12
    bodies = [
        *base,
        *([1.0, e, 2.0] for e in edge),
        *([e, 2.0, 2.0 * e] for e in edge),
        *([2.0, 1.0, e] for e in edge),
        [1.0, 1.0, 1.0],
        [3.0, 3.0, 3.0 + 1e-11],
    ]
    for k in range(1, 4):  # symmetric about each axis, in either order
        for body in base[:200]:
            bodies.append(np.roll([body[0], body[0], body[1]], k))
    many = symmetry_axes(np.array(bodies))
    assert set(many) == {-1, 0, 1, 2}
    for body, axis in zip(bodies, many, strict=True):
        assert symmetry_axis(body) == (None if axis < 0 else axis), body
