"""Scenes: parsing, frames, and one-line errors naming source, key path, value and fix."""

import math

import numpy as np
import pytest
from helpers import abaqus_mapping
from scipy.spatial.transform import Rotation

from rbstudy.errors import SceneError
from rbstudy.inputs.scenes import scene_from_mapping


def fails(mapping, message):
    with pytest.raises(SceneError) as info:
        scene_from_mapping(mapping, source="top.yaml")
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith("top.yaml: ")
    assert message in text, text


def test_non_positive_inertia_is_rejected():
    fails({"body": {"inertia": [1.0, -1.0, 1.0]}}, "scene.body.inertia[1]: must be > 0 kg m^2, got -1.0")
    fails({"body": {"inertia": [1.0, 0, 1.0]}}, "scene.body.inertia[1]: must be > 0")


def test_non_finite_values_are_rejected():
    fails({"body": {"inertia": [1.0, 1.0, float("nan")]}}, "scene.body.inertia[2]: must be finite, got nan")
    fails(
        {"body": {"inertia": [1, 1, 1]}, "initial": {"velocity": [0, float("inf"), 0]}},
        "scene.initial.velocity[1]: must be finite",
    )


def test_triangle_inequality_unless_flagged():
    fails(
        {"body": {"inertia": [1.0, 1.0, 2.5]}},
        "violates the triangle inequality I1 + I2 >= I3 (and cyclic): no rigid body has it; "
        "set allow_unphysical: true",
    )
    scene = scene_from_mapping({"body": {"inertia": [1.0, 1.0, 2.5], "allow_unphysical": True}})
    assert not scene.body.physical and scene.body.allow_unphysical


def test_flat_disk_at_the_edge_is_physical():
    assert scene_from_mapping(abaqus_mapping()).body.physical


def test_unknown_keys_and_wrong_types_are_named():
    fails(
        {"body": {"inertia": [1, 1, 1], "mas": 2}},
        "scene.body.mas: unknown key (did you mean 'mass'?); valid keys here: mass, inertia, "
        "allow_unphysical",
    )
    fails(
        {"body": {"inertia": [1, 1, 1], "mass": "heavy"}}, "scene.body.mass: expected a number, got 'heavy'"
    )
    fails({"body": {"inertia": [1, 1]}}, "scene.body.inertia: expected a list of 3 numbers")
    fails({"body": {"inertia": [1, 1, 1]}, "duration": 0}, "scene.duration: must be > 0, got 0")


def test_momentum_axis_needs_body_angular_velocity():
    mapping = abaqus_mapping()
    mapping["initial"]["angular_velocity"] = {"space": [0, 0, 1]}
    fails(mapping, "scene.initial.orientation.momentum_axis: needs the angular velocity in body")


def test_momentum_axis_puts_l_on_the_axis():
    for axis in ([0, 0, 1], [1, 2, -0.5], [0, 0, -1]):
        mapping = abaqus_mapping()
        mapping["initial"]["orientation"] = {"momentum_axis": axis}
        scene = scene_from_mapping(mapping)
        momentum = Rotation.from_quat(scene.quaternion).apply(np.array(scene.body.inertia) * scene.omega_body)
        direction = np.array(axis) / np.linalg.norm(axis)
        assert np.allclose(momentum / np.linalg.norm(momentum), direction, atol=1e-14)


def test_inertia_tensor_is_diagonalised_and_vectors_follow():
    turn = Rotation.from_rotvec([0.3, 0.4, -0.2])
    principal = np.diag([1.0, 2.0, 2.5])
    tensor = turn.as_matrix() @ principal @ turn.as_matrix().T
    omega_input = np.array([0.3, -1.0, 2.0])
    scene = scene_from_mapping(
        {
            "body": {"inertia": tensor.tolist()},
            "initial": {"angular_velocity": {"body": omega_input.tolist()}},
            "nodes": {"tip": [1.0, 0.0, 0.0]},
        }
    )
    assert np.allclose(scene.body.inertia, [1.0, 2.0, 2.5])
    # same physics in both frames: energy, and the node seen from space
    energy_input = 0.5 * omega_input @ tensor @ omega_input
    energy = 0.5 * np.sum(np.array(scene.body.inertia) * np.array(scene.omega_body) ** 2)
    assert math.isclose(energy, energy_input, rel_tol=1e-13)
    node_space = Rotation.from_quat(scene.quaternion).apply(scene.nodes[0])
    assert np.allclose(node_space, [1.0, 0.0, 0.0], atol=1e-14)


def test_space_angular_velocity_is_turned_into_the_body():
    scene = scene_from_mapping(
        {
            "body": {"inertia": [1, 2, 3]},
            "initial": {
                "angular_velocity": {"space": [0.0, 0.0, 2.0]},
                "orientation": {"euler_zxz_deg": [10, 30, 50]},
            },
        }
    )
    space = Rotation.from_quat(scene.quaternion).apply(scene.omega_body)
    assert np.allclose(space, [0.0, 0.0, 2.0], atol=1e-14)


def test_a_symmetric_body_given_as_a_rotated_tensor_is_symmetric(tmp_path):
    """diag(1, 1, 2) turned by a rotation diagonalises to (1.0, 1.0000000000000004, 2.0): it is
    still the symmetric top, with its closed-form reference and precession variables."""
    from helpers import write_study

    from rbstudy.inputs.scenes import scene_table
    from rbstudy.physics.analytic import precession_frequency_exact
    from rbstudy.pipeline.config import load_study

    turn = Rotation.from_rotvec([0.4, -0.7, 0.2]).as_matrix()
    tensor = turn @ np.diag([1.0, 1.0, 2.0]) @ turn.T
    assert len(set(np.linalg.eigh(tensor)[0])) == 3  # round-off makes the values differ
    w_input = turn @ np.array([0.25, 0.0, 2.0 * math.pi])  # (A, 0, w3) in principal axes
    scene_spec = {
        "body": {"inertia": tensor.tolist()},
        "initial": {"angular_velocity": {"body": w_input.tolist()}},
        "duration": 0.5,
    }
    scene = scene_from_mapping(scene_spec)
    assert scene.body.symmetry_axis is not None
    assert list(scene_table(scene_spec).reference_kinds) == ["symmetric_top"]
    assert math.isclose(abs(precession_frequency_exact(scene)), 2.0 * math.pi, rel_tol=1e-12)
    study = load_study(write_study(tmp_path, scene=scene_spec))
    assert {"precession_frequency", "precession_frequency_error"} <= set(study.variables)
    assert "flip_interval" not in study.variables


def test_the_table_s_rows_are_the_scenes_rows_bit_for_bit():
    """The pipeline takes state and parameter rows straight from a sweep's columns; they are
    the rows each `Scene` packs, bit for bit: a swept near-symmetric tensor (whose two
    transverse moments each `Body` makes equal), nodal forces, a load table scaled per scene
    and a damping, rows taken out of order and twice."""
    from rbstudy.inputs.scenes import scene_table
    from rbstudy.numerics import state as S
    from rbstudy.physics.scenes import param_rows

    size = 5
    turn = Rotation.from_rotvec([0.4, -0.7, 0.2]).as_matrix()
    tensor = turn @ np.diag([1.0, 1.0, 2.0]) @ turn.T  # diagonalises to 1.0, 1.0000000000000004
    table = scene_table(
        {
            "body": {"inertia": [[np.linspace(1.0, 2.0, size), 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 3.0]]},
            "nodes": {"tip": [0.1, 0.2, np.linspace(0.3, 0.7, size)]},
            "initial": {
                "angular_velocity": {"body": [np.linspace(0.1, 0.5, size), 2.0, 30.0]},
                "orientation": {"euler_zxz_deg": [10.0, 20.0, 30.0]},
                "velocity": [1.0, 0.0, 0.0],
            },
            "loads": {
                "moment_space": {
                    "table": [[0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 2.0, 3.0]],
                    "scale": np.arange(size),
                },
                "damping_moment": [0.1, 0.0, 0.2],
                "nodes": {"tip": {"force_space": [0.0, np.linspace(-1.0, 1.0, size), 4.0]}},
            },
            "duration": 2.0,
        },
        size=size,
    )
    rotated = scene_table({"body": {"inertia": tensor.tolist()}})
    assert rotated.inertia[0, 0] != rotated.inertia[0, 1]  # as read, before the Body's symmetry
    for scenes, rows in ((table, np.array([3, 0, 4, 4, 1])), (rotated, np.array([0]))):
        views = [scenes.scene(row) for row in rows]
        taken = scenes.batch_rows(rows)
        assert taken.states.tobytes() == np.array([scene.state_row() for scene in views]).tobytes()
        assert taken.params.tobytes() == param_rows(views).tobytes()
        assert taken.duration == views[0].duration
    assert table.batch_rows(np.arange(size)).params[:, S.KNOTS].tolist() == [2.0] * size  # two knots
    assert table.timed.tolist() == [False, True, True, True, True]  # the scale of row 0 is 0
