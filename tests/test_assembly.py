"""Bodies assembled from nodes (the Radioss rigid body): hand-computable bodies, the continuous
limit, invariance under moving the input, the Radioss options and errors, and the body built
two ways integrating alike."""

import math

import numpy as np
import pytest
from helpers import write_study
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rbstudy.cli import main
from rbstudy.errors import ConfigError, SceneError
from rbstudy.inputs.scenes import scene_from_mapping, scene_table
from rbstudy.physics.assembly import REGULARISATION
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.schemes import BUILTIN

FIXED_STEP = [name for name, scheme in BUILTIN.items() if not scheme.adaptive]


def assembled(nodes, **options):
    """The scene of secondary nodes ``{name: (position, mass)}`` (plus assembly options)."""
    block = {
        "nodes": {
            name: {"position": list(map(float, position)), "mass": float(mass)}
            for name, (position, mass) in nodes.items()
        },
        **options,
    }
    return scene_from_mapping(
        {"assembly": block, "initial": {"angular_velocity": {"space": [0.0, 0.0, 1.0]}}}
    )


def space_tensor(scene):
    """The scene's inertia tensor about its centre of mass, in space axes at t = 0."""
    turn = Rotation.from_quat(scene.quaternion).as_matrix()
    return turn @ np.diag(scene.body.inertia) @ turn.T


def node_positions(scene):
    """Where the scene puts its nodes in space at t = 0."""
    return np.array(scene.position) + Rotation.from_quat(scene.quaternion).apply(scene.nodes)


def by_hand(positions, masses):
    """m, x_G and sum m_i (|d_i|^2 1 - d_i d_i^T), one node at a time."""
    total = sum(masses)
    centre = sum(m * np.asarray(x) for x, m in zip(positions, masses, strict=True)) / total
    tensor = np.zeros((3, 3))
    for x, m in zip(positions, masses, strict=True):
        d = np.asarray(x) - centre
        tensor += m * (d @ d * np.eye(3) - np.outer(d, d))
    return total, centre, tensor


def test_a_dumbbell_of_two_spheres():
    """Spheres (nodal inertia 2/5 m r^2) of mass 2 at the ends of a rod of length 3 along
    (1, 1, 0): axial inertia 2 (2/5 m r^2), transverse that plus 2 m (L/2)^2."""
    m, r, length = 2.0, 0.25, 3.0
    sphere = 0.4 * m * r * r
    direction = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    ends = [
        list(+0.5 * length * direction + [1.0, 2.0, 3.0]),
        list(-0.5 * length * direction + [1.0, 2.0, 3.0]),
    ]
    scene = scene_from_mapping(
        {
            "assembly": {
                "nodes": {
                    f"end{k}": {"position": end, "mass": m, "inertia": [sphere] * 3 + [0.0] * 3}
                    for k, end in enumerate(ends)
                }
            }
        }
    )
    axial = 2 * sphere
    transverse = axial + 2 * m * (0.5 * length) ** 2
    assert scene.body.mass == 4.0 and np.allclose(scene.position, [1.0, 2.0, 3.0])
    assert np.allclose(scene.body.inertia, [axial, transverse, transverse], rtol=1e-14)
    # the axial principal axis (the smallest inertia, first) lies along the rod
    axis = Rotation.from_quat(scene.quaternion).apply([1.0, 0.0, 0.0])
    assert math.isclose(abs(axis @ direction), 1.0, rel_tol=1e-14)
    assert np.allclose(node_positions(scene), ends, atol=1e-14)


def test_a_cube_of_eight_nodes_and_the_centre_options():
    """Eight nodes of 1/8 kg at (+-1, +-1, +-1): I = 2 on every axis about the centre; pinned
    at a master at (0.3, 0, 0), the parallel-axis rule adds m (|d|^2 1 - d d^T)."""
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    nodes = {f"c{k}": (corner, 0.125) for k, corner in enumerate(corners)}
    master = {"position": [0.3, 0.0, 0.0]}
    cube = assembled(nodes, master=master)
    assert cube.body.inertia == pytest.approx((2.0, 2.0, 2.0), rel=1e-15)
    assert np.allclose(cube.position, 0.0)
    pinned = assembled(nodes, master=master, centre_of_mass="master")
    d = np.array([0.3, 0.0, 0.0])
    assert np.allclose(space_tensor(pinned), 2.0 * np.eye(3) + 1.0 * (d @ d * np.eye(3) - np.outer(d, d)))
    assert np.allclose(pinned.position, d)
    # a heavy master moves "all" but not "secondaries"
    heavy = {"position": [0.3, 0.0, 0.0], "mass": 1.0}
    assert np.allclose(assembled(nodes, master=heavy).position, [0.15, 0.0, 0.0])
    assert np.allclose(assembled(nodes, master=heavy, centre_of_mass="secondaries").position, 0.0)


@pytest.mark.slow
def test_a_node_cloud_in_a_solid_ellipsoid_tends_to_the_continuous_body():
    """Lattice nodes inside a solid ellipsoid of semi-axes (3, 2, 1) and mass 1: the principal
    inertias approach (b^2 + c^2, a^2 + c^2, a^2 + b^2) / 5 as the lattice is refined."""
    a, b, c = 3.0, 2.0, 1.0
    exact = np.array(sorted([b * b + c * c, a * a + c * c, a * a + b * b])) / 5.0
    errors = []
    for spacing in (0.4, 0.2, 0.1):
        axis = np.arange(-a, a + spacing / 2, spacing)
        grid = np.array(np.meshgrid(axis, axis, axis)).reshape(3, -1).T
        inside = grid[((grid / [a, b, c]) ** 2).sum(axis=1) <= 1.0]
        spec = {
            "assembly": {
                "nodes": {
                    f"n{k}": {"position": list(x), "mass": 1.0 / len(inside)}
                    for k, x in enumerate(inside.tolist())
                }
            }
        }
        errors.append(np.max(np.abs(np.array(scene_from_mapping(spec).body.inertia) / exact - 1)))
    assert errors[0] > errors[1] > errors[2] and errors[2] < 0.01, errors


# A node cloud: 3 to 9 nodes in a 10 m box, masses 0.1 to 10 kg.
clouds = st.integers(3, 9).flatmap(
    lambda n: st.tuples(
        st.lists(st.tuples(*[st.floats(-5.0, 5.0)] * 3), min_size=n, max_size=n),
        st.lists(st.floats(0.1, 10.0), min_size=n, max_size=n),
    )
)
turns = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1)


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(clouds, turns, st.tuples(*[st.floats(-100.0, 100.0)] * 3))
def test_moving_the_input_moves_the_body_and_nothing_else(cloud, turn, shift):
    """Turning and shifting every node leaves the principal inertias alone and turns the
    inertia tensor with the nodes; the scene puts every node back where it was given, and
    its tensor is the one computed node by node (regularised by hand where it is thin)."""
    positions, masses = cloud
    total, centre, tensor = by_hand(positions, masses)
    values, axes = np.linalg.eigh(tensor)
    if values[0] <= 1e-6 * values[2]:
        return  # nodes (nearly) on a line: refused, tested below
    # a thin cloud has its smallest inertia raised to 1e-3 of the largest (Radioss)
    values = np.maximum(values, REGULARISATION * values[2])
    tensor = axes @ np.diag(values) @ axes.T
    rotation = Rotation.from_quat(turn)
    moved = rotation.apply(positions) + shift
    for given_positions in (positions, moved):
        scene = assembled(
            {
                f"n{k}": (x, m)
                for k, (x, m) in enumerate(zip(np.asarray(given_positions), masses, strict=True))
            }
        )
        assert math.isclose(scene.body.mass, total, rel_tol=1e-14)
        assert np.allclose(scene.body.inertia, values, rtol=1e-9, atol=1e-12 * values[2])
        assert np.allclose(
            node_positions(scene), given_positions, atol=1e-9 * (1.0 + np.abs(given_positions).max())
        )
    moved_scene = assembled({f"n{k}": (x, m) for k, (x, m) in enumerate(zip(moved, masses, strict=True))})
    turned = rotation.as_matrix() @ tensor @ rotation.as_matrix().T
    assert np.allclose(space_tensor(moved_scene), turned, atol=1e-9 * values[2])


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 1e-6), st.integers(0, 7), turns)
def test_a_nearly_degenerate_cloud_keeps_a_right_handed_frame(nudge, which, turn):
    """A cube (every principal inertia equal) with one node nudged: the principal axes are
    right-handed and orthonormal, and the nodes are put back where they were given."""
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1]), float).reshape(3, -1).T
    corners[which] *= 1.0 + nudge
    corners = Rotation.from_quat(turn).apply(corners)
    scene = assembled({f"c{k}": (x, 0.125) for k, x in enumerate(corners)})
    assert np.allclose(node_positions(scene), corners, atol=1e-12)
    # the frame diagonalises the cloud's tensor, computed here from the corners
    offsets = corners - corners.mean(axis=0)
    tensor = 0.125 * (np.sum(offsets**2) * np.eye(3) - offsets.T @ offsets)
    frame = Rotation.from_quat(scene.quaternion).as_matrix()
    assert np.allclose(frame.T @ tensor @ frame, np.diag(scene.body.inertia), atol=1e-12)


@pytest.mark.parametrize(
    "block, message",
    [
        (
            {
                "nodes": {
                    "a": {"position": [1, 0, 0], "mass": -1.0},
                    "b": {"position": [0, 1, 0], "mass": 1.0},
                }
            },
            "scene.assembly.nodes.a.mass: a node's mass must be >= 0, got -1.0; give a mass >= 0 kg",
        ),
        (
            {"nodes": {"a": {"position": [1, 0, 0], "mass": 0.0}}},
            "scene.assembly.nodes: the body has no mass; give a node (or the master) a mass > 0 kg",
        ),
        (
            {"nodes": {"a": {"position": [1, 0, 0], "mass": 1.0}, "b": {"position": [2, 0, 0], "mass": 1.0}}},
            "scene.assembly.nodes: principal inertias [0.0, 0.5, 0.5]: the nodes lie on one line",
        ),
        (
            {"nodes": {"a": {"position": [1, 0, float("nan")], "mass": 1.0}}},
            "scene.assembly.nodes.a.position[2]: must be finite, got nan",
        ),
        (
            {"nodes": {"a": {"position": [1, 0, 0]}}},
            "scene.assembly.nodes.a.mass: missing; give every node a position (m) and a mass (kg)",
        ),
        (
            {"nodes": {"a": {"position": [1, 0, 0], "mass": 1.0}}, "centre_of_mass": "middle"},
            "scene.assembly.centre_of_mass: expected one of all, secondaries, master, got 'middle'",
        ),
    ],
)
def test_bad_nodes_are_named_with_the_fix(block, message):
    with pytest.raises(SceneError) as error:
        scene_from_mapping({"assembly": block}, source="body.yaml")
    assert str(error.value).startswith(f"body.yaml: {message}"), error.value


@pytest.mark.parametrize(
    "extra, key",
    [
        ({"body": {"mass": 1.0, "inertia": [1.0, 1.0, 1.0]}}, "scene.body"),
        ({"nodes": {"tip": [1.0, 0.0, 0.0]}}, "scene.nodes"),
        ({"initial": {"orientation": {"quaternion": [0, 0, 0, 1]}}}, "scene.initial.orientation"),
    ],
)
def test_what_the_nodes_imply_is_never_given_twice(extra, key):
    spec = {"assembly": {"nodes": {"a": {"position": [0, 0, 0], "mass": 1.0}}, "spherical": True}, **extra}
    with pytest.raises(SceneError, match=rf"{key}: an assembled body.*; remove {key}$"):
        scene_from_mapping(spec)


def test_spherical_and_regularised_bodies():
    """Spherical: trace / 3 on every axis. A flat body (principal inertia below 1e-3 of the
    largest) is raised to 1e-3 of it, with a warning that counts the scenes."""
    square = {f"s{k}": ((x, y, 0.0), 1.0) for k, (x, y) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)])}
    assert assembled(square, spherical=True).body.inertia == pytest.approx((16 / 3,) * 3)
    thin = {
        "nodes": {
            f"s{k}": {"position": [x, y, z], "mass": 1.0}
            for k, (x, y, z) in enumerate([(1, 1e-3, 0), (-1, -1e-3, 0), (0, 0, 1e-3), (0, 0, -1e-3)])
        }
    }
    table = scene_table({"assembly": thin})
    inertia = table.scene(0).body.inertia
    assert inertia[0] == pytest.approx(REGULARISATION * inertia[2], rel=1e-12)
    assert table.warnings == (
        "scene.assembly: a principal inertia below 0.001 of the largest "
        "was raised to it in 1 of 1 scenes (Radioss regularisation)",
    )


def test_the_radioss_regression_models():
    """(a) a master of added spherical inertia 1 and negligible mass with one massless
    secondary at (1, 0, 0), 2 rad/s about z for 10 s at dt = 1e-3: energy 2, the secondary on
    its unit circle. (b) master of mass 10 and added spherical inertia 1, centre pinned at the
    master, massless secondaries at (0,1,0), (0,2,0), (0,1,1), 1 rad/s about z for 6.29 s at
    dt = 0.01: energy 0.5 and every secondary back near its start after one turn."""
    model_a = scene_from_mapping(
        {
            "assembly": {
                "master": {"mass": 1e-9, "inertia": 1.0},
                "nodes": {"tip": {"position": [1.0, 0.0, 0.0], "mass": 0.0}},
            },
            "initial": {"angular_velocity": {"space": [0.0, 0.0, 2.0]}},
            "duration": 10.0,
        }
    )
    starts = [[0.0, 1.0, 0.0], [0.0, 2.0, 0.0], [0.0, 1.0, 1.0]]
    model_b = scene_from_mapping(
        {
            "assembly": {
                "master": {"mass": 10.0, "inertia": 1.0},
                "centre_of_mass": "master",
                "nodes": {f"s{k}": {"position": x, "mass": 0.0} for k, x in enumerate(starts)},
            },
            "initial": {"angular_velocity": {"space": [0.0, 0.0, 1.0]}},
            "duration": 6.29,
        }
    )
    for name in FIXED_STEP:
        run = simulate([model_a], name, 1e-3, 0.1)
        energy = 0.5 * np.sum(np.array(model_a.body.inertia) * run.omega_body[0] ** 2, axis=-1)
        assert np.allclose(energy, 2.0, rtol=1e-12), name
        tip = np.array([Rotation.from_quat(q).apply(model_a.nodes[0]) for q in run.quaternion[0]])
        assert np.allclose(np.hypot(tip[:, 0], tip[:, 1]), 1.0, rtol=1e-12) and np.allclose(
            tip[:, 2], 0.0, atol=1e-12
        ), name
        run = simulate([model_b], name, 0.01, 0.01)
        energy = 0.5 * np.sum(np.array(model_b.body.inertia) * run.omega_body[0, -1] ** 2)
        assert math.isclose(energy, 0.5, rel_tol=1e-12), name
        back = Rotation.from_quat(run.quaternion[0, -1]).apply(model_b.nodes) + model_b.position
        # on their circles about z, and 6.29 s turn them by 6.29 rad: 0.007 rad (1.4 cm at
        # 2 m) past their start, give or take a scheme's phase error (midpoint: 5e-5 rad)
        assert np.allclose(np.hypot(back[:, 0], back[:, 1]), [1.0, 2.0, 1.0], rtol=1e-12)
        assert np.allclose(back[:, 2], [0.0, 0.0, 1.0], atol=1e-12), name
        assert np.max(np.linalg.norm(back - starts, axis=1)) < 0.015, name


@pytest.mark.parametrize("loaded", [False, True], ids=["free", "loaded"])
@pytest.mark.parametrize("scheme", FIXED_STEP)
def test_the_body_built_from_nodes_and_given_by_its_inertia_move_alike(scheme, loaded):
    """Six nodes of 1 kg on the axes of a box (half sides 1, 2, 3 m along x, y, z) make the
    principal inertias 2 (a^2 + b^2) = 10 about z, 2 (a^2 + c^2) = 20 about y and
    2 (b^2 + c^2) = 26 about x. The same body given by its mass and principal inertias
    (10, 20, 26), its axes turned onto z, y and -x, spun alike, moves every node through
    space alike over 1,000 steps, to round-off: free, and loaded by a space-fixed force at
    one node, a body force at another and gravity (each scene working out their moments in
    its own principal frame).

    The principal axes of an assembled body come in ascending order of inertia; the
    splitting schemes' ``axis_order`` counts in that order, so a body given with its
    inertias in another order is split in another order (another error constant)."""
    half = {"x": 1.0, "y": 2.0, "z": 3.0}
    nodes = {
        f"{sign}{axis}": {"position": [s * half[axis] * (axis == k) for k in "xyz"], "mass": 1.0}
        for axis in "xyz"
        for sign, s in (("p", 1.0), ("m", -1.0))
    }
    omega = np.array([0.3, 1.1, -0.7])
    axes = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # columns z, y, -x
    positions = np.array([node["position"] for node in nodes.values()])
    push, turn = np.array([0.5, -1.0, 2.0]), np.array([0.0, 0.8, 0.3])  # N
    # the body force in each body's own axes: space axes at t = 0 for the built one
    loads = (
        {
            given: {
                "gravity": [0.0, 0.0, -9.81],
                "nodes": {
                    "px": {"force_space": push.tolist()},
                    "mz": {"force_body": (axes.T @ turn if given else turn).tolist()},
                },
            }
            for given in (False, True)
        }
        if loaded
        else {False: {}, True: {}}
    )
    built = scene_from_mapping(
        {
            "assembly": {"nodes": nodes},
            "initial": {"angular_velocity": {"space": omega.tolist()}},
            "loads": loads[False],
            "duration": 1.0,
        }
    )
    given_body = scene_from_mapping(
        {
            "body": {"mass": 6.0, "inertia": [10.0, 20.0, 26.0]},
            "nodes": {name: row.tolist() for name, row in zip(nodes, positions @ axes, strict=True)},
            "initial": {
                "angular_velocity": {"body": (axes.T @ omega).tolist()},
                "orientation": {"quaternion": Rotation.from_matrix(axes).as_quat().tolist()},
            },
            "loads": loads[True],
            "duration": 1.0,
        }
    )
    paths = []
    for scene in (built, given_body):
        run = simulate([scene], scheme, 1e-3, 0.1)
        turns = Rotation.from_quat(run.quaternion[0])
        paths.append(
            np.array([turn.apply(scene.nodes) + x for turn, x in zip(turns, run.position[0], strict=True)])
        )
    assert np.allclose(paths[1][0], positions, atol=1e-15)
    size = np.max(np.abs(paths[1]))
    assert np.max(np.abs(paths[0] - paths[1])) <= 1e-12 * size, scheme


def test_a_study_sweeps_node_masses_and_the_cloud_and_says_what_it_regularised(tmp_path, capsys):
    """A study of an assembled body sweeps a node's mass and the cloud's scale like any
    value; validate prints the regularisation as a warning of the file; inertia_ratio is
    refused for it with the reason."""
    thin = {
        "assembly": {
            "nodes": {
                "a": {"position": [1.0, 1e-3, 0.0], "mass": 1.0},
                "b": {"position": [-1.0, -1e-3, 0.0], "mass": 1.0},
                "c": {"position": [0.0, 0.0, 1e-3], "mass": 1.0},
            }
        },
        "initial": {"angular_velocity": {"space": [0.0, 0.0, 1.0]}},
        "duration": 0.5,
    }
    path = write_study(
        tmp_path,
        scene=thin,
        sweep={"scene.assembly.nodes.a.mass": [1.0, 2.0], "scene.assembly.scale": [0.5, 1.0, 2.0]},
    )
    study = load_study(path)
    masses = [case.scene.body.mass for case in study.cases]
    assert masses == [3.0] * 3 + [4.0] * 3
    # scaling the cloud about the master (the origin) scales every inertia by scale^2
    ratio = np.array(study.cases[2].scene.body.inertia) / study.cases[1].scene.body.inertia
    assert np.allclose(ratio, 4.0, rtol=1e-12)
    assert main(["validate", str(path)]) == 0
    # a line of its own (wrapped at 100 columns, its continuations indented)
    out = "\n".join(capsys.readouterr().out.splitlines()).replace("\n  ", " ").splitlines()
    assert out[1] == (
        f"{path}: warning: scene.assembly: a principal inertia below 0.001 of "
        "the largest was raised to it in 6 of 6 scenes (Radioss regularisation)"
    )
    bad = write_study(tmp_path, name="bad", scene=thin, sweep={"inertia_ratio": [1.0]})
    with pytest.raises(
        ConfigError,
        match="scene.assembly: inertia_ratio has no meaning for a "
        "body assembled from nodes; sweep its nodes' masses",
    ):
        load_study(bad)
