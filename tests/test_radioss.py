"""The Radioss rigid body under load: nodal loads aggregated to the centre of mass, the
Radioss stability check, the lagged gyroscopic term of its own integrator, node tables."""

import math

import numpy as np
import pytest
from helpers import FIXED_STEP, ROUND_OFF_FLOOR, independent_reference, write_study
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from rbstudy.analysis.plots import stability_map
from rbstudy.analysis.summary import format_table, scheme_rows
from rbstudy.archive.load import open_results
from rbstudy.errors import InputError, SceneError
from rbstudy.inputs.scenes import scene_from_mapping, scene_table
from rbstudy.numerics import state as S
from rbstudy.numerics.dynamics import body_moment
from rbstudy.physics.metrics import asymptotic_order, orientation_error
from rbstudy.physics.references import reference_solution
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.schemes import BUILTIN, SCHEMES

# An asymmetric body of four nodes (a skewed tetrahedron) with a master of its own mass.
NODES = {
    "1": {"position": [1.0, 0.2, 0.0], "mass": 2.0},
    "2": {"position": [-0.8, 0.5, 0.1], "mass": 1.0},
    "3": {"position": [0.1, -1.2, 0.3], "mass": 1.5},
    "4": {"position": [0.2, 0.1, 0.9], "mass": 0.5},
}
MASTER = {"position": [0.1, 0.0, 0.2], "mass": 1.0}


def loaded(loads, spin=(0.4, 1.1, -0.6), velocity=(0.0, 0.0, 0.0), duration=2.0, **assembly):
    """The asymmetric assembled body, spun (rad/s, space axes) and loaded."""
    return scene_from_mapping(
        {
            "assembly": {"master": MASTER, "nodes": NODES, **assembly},
            "initial": {"angular_velocity": {"space": list(spin)}, "velocity": list(velocity)},
            "loads": loads,
            "duration": duration,
        },
        source="test",
    )


def space_points(scene):
    """Offsets of the nodes from the centre of mass in space axes at t = 0, by name."""
    turn = Rotation.from_quat(scene.quaternion)
    return dict(zip(scene.node_names, turn.apply(scene.nodes), strict=True))


def independent_run(scene, forces, times):
    """The scene's motion under space-fixed ``forces`` {node: F} at its nodes, by scipy's
    RK45 at tight tolerance on rotation matrices, written from Euler's equations alone:
    ``I dw/dt = R^T sum (R d_i) x F_i - w x I w``, ``dR/dt = R [w]x``, ``m dv/dt = sum F_i``."""
    inertia = np.array(scene.body.inertia)
    offsets = dict(zip(scene.node_names, scene.nodes, strict=True))
    total = sum(np.asarray(f, dtype=float) for f in forces.values())

    def rates(t, y):
        turn, w, v = y[:9].reshape(3, 3), y[9:12], y[15:18]
        moment = sum(np.cross(turn @ offsets[name], f) for name, f in forces.items())
        dw = (turn.T @ moment - np.cross(w, inertia * w)) / inertia
        skew = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        return np.concatenate([(turn @ skew).ravel(), dw, v, total / scene.body.mass])

    start = np.concatenate(
        [
            Rotation.from_quat(scene.quaternion).as_matrix().ravel(),
            scene.omega_body,
            scene.position,
            scene.velocity,
        ]
    )
    solution = solve_ivp(
        rates, (0.0, times[-1]), start, method="DOP853", t_eval=times, rtol=1e-12, atol=1e-12
    )
    return Rotation.from_matrix(solution.y[:9].T.reshape(-1, 3, 3)), solution.y[12:15].T


def test_nodal_forces_give_the_force_sum_and_r_cross_f_at_any_orientation():
    """Space and body forces and moments at the nodes and the master: F = sum F_i and
    M = sum M_i + sum r_i x F_i about the centre of mass, at t = 0 and at any later
    orientation (the space forces' moment turns with the body, the body forces' with it)."""
    loads = {
        "nodes": {
            "1": {"force_space": [0.0, 3.0, -1.0], "moment_space": [0.5, 0.0, 0.0]},
            "3": {"force_body": [1.0, 0.0, 2.0], "moment_body": [0.0, 0.0, 0.7]},
            "master": {"force_space": [-2.0, 0.0, 0.5]},
        }
    }
    scene = loaded(loads)
    r = space_points(scene)
    turn0 = Rotation.from_quat(scene.quaternion)
    master = np.array(MASTER["position"]) - scene.position
    p = scene.param_row()
    space_forces = {"1": np.array([0.0, 3.0, -1.0]), "master": np.array([-2.0, 0.0, 0.5])}
    body_force = np.array([1.0, 0.0, 2.0])  # in the body axes, which are space's at t = 0
    for later in Rotation.random(5, random_state=1):
        turn = later * turn0  # the body turned by `later` from its start
        moment = (
            later.apply(np.cross(r["3"], body_force) + [0.0, 0.0, 0.7])
            + np.cross(later.apply(r["1"]), space_forces["1"])
            + np.cross(later.apply(master), space_forces["master"])
            + [0.5, 0.0, 0.0]
        )
        expected = turn.inv().apply(moment)
        got = np.array(body_moment(turn.as_quat(), np.zeros(3), p, 0.0))
        assert np.allclose(got, expected, rtol=1e-13, atol=1e-13)
        force = space_forces["1"] + space_forces["master"] + later.apply(body_force)
        assert np.allclose(
            p[S.FORCE_SPACE : S.FORCE_SPACE + 3] + turn.apply(p[S.FORCE_BODY : S.FORCE_BODY + 3]),
            force,
            rtol=1e-13,
        )


def test_a_force_through_the_centre_of_mass_turns_nothing():
    """A space force along the line from the centre of mass to its node, on a body at rest:
    no rotation, the centre of mass on its parabola (every scheme)."""
    at_rest = loaded({}, spin=(0.0, 0.0, 0.0))
    along = space_points(at_rest)["2"]
    scene = loaded({"nodes": {"2": {"force_space": (4.0 * along).tolist()}}}, spin=(0.0, 0.0, 0.0))
    for name in FIXED_STEP:
        run = simulate([scene], name, 0.01, 0.1)
        assert np.max(np.abs(run.omega_body[0])) < 1e-12, name
        assert np.max(orientation_error(run.quaternion[0], scene.quaternion)) < 1e-12, name
        travel = 0.5 * 4.0 * along / scene.body.mass * run.time[-1] ** 2
        assert np.allclose(run.position[0, -1] - scene.position, travel, rtol=0.02), name


def test_a_space_fixed_nodal_force_moves_the_body_as_euler_s_equations_say():
    """rk4 at a fine step against an independent integration (rotation matrices, the moment
    summed node by node in space): the lever the kernels carry is the physics."""
    forces = {"1": [0.0, 3.0, -1.0], "4": [1.5, 0.0, 0.0]}
    scene = loaded({"nodes": {name: {"force_space": f} for name, f in forces.items()}})
    run = simulate([scene], "rk4", 1e-3, 0.1)
    turns, position = independent_run(scene, forces, run.time)
    assert np.max(orientation_error(run.quaternion[0], turns.as_quat())) < 1e-9
    assert np.max(np.abs(run.position[0] - position)) < 1e-9
    assert reference_solution(scene, run.time).name == "exact_split_composition"


@pytest.mark.parametrize("name", FIXED_STEP)
def test_a_space_fixed_nodal_force_keeps_each_scheme_s_order(name):
    """A space-fixed force at an offset node (its moment turns with the body) plus gravity:
    every scheme at its nominal order against the tight reference, in the orientation."""
    scene = loaded({"gravity": [0.0, 0.0, -9.81], "nodes": {"3": {"force_space": [2.0, -1.0, 4.0]}}})
    dts = 0.08 / 2.0 ** np.arange(5)
    runs = [simulate([scene], name, dt, 0.08) for dt in dts]
    reference = independent_reference(scene, runs[0].time, name).quaternion
    errors = [orientation_error(r.quaternion[0, -1], reference[-1]) for r in runs]
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    assert used.sum() >= 3 and abs(order - SCHEMES[name].order) <= 0.25, (order, errors)


def test_a_couple_of_nodal_forces_about_a_principal_axis_is_the_axial_closed_form():
    """Opposite body forces at two nodes on the x axis of a body spinning about its z axis: a
    pure axial moment 2 F a, the closed form applies (and the splitting scheme is exact)."""
    scene = scene_from_mapping(
        {
            "body": {"mass": 2.0, "inertia": [1.0, 2.0, 2.5]},
            "nodes": {"a": [0.5, 0.0, 0.0], "b": [-0.5, 0.0, 0.0]},
            "initial": {"angular_velocity": {"body": [0.0, 0.0, 3.0]}},
            "loads": {"nodes": {"a": {"force_body": [0.0, 0.8, 0.0]}, "b": {"force_body": [0.0, -0.8, 0.0]}}},
            "duration": 2.0,
        },
        source="test",
    )
    assert scene.loads.moment_body == (0.0, 0.0, 0.8) and not any(scene.loads.force_body)
    run = simulate([scene], "splitting", 0.01, 0.1)
    reference = reference_solution(scene, run.time)
    assert reference.name == "axial_moment"
    assert np.allclose(run.omega_body[0, :, 2], 3.0 + 0.8 / 2.5 * run.time, rtol=1e-14)
    assert np.max(orientation_error(run.quaternion[0], reference.quaternion)) < 1e-12


def test_gravity_on_a_body_centred_elsewhere_pulls_at_the_mass():
    """Gravity acts on every mass: about the centre of mass it gives no moment, nor about the
    secondaries' own centre when the master has no mass (exactly: the body stays
    moment-free); about a centre taken at the master its moment is (sum m_j d_j) x g, as if
    each node were pulled by m_j g."""
    gravity = [0.0, 0.0, -9.81]
    free = loaded({"gravity": gravity}, spin=(0.0, 0.0, 2.0))
    assert free.loads.moment_free
    massless_master = scene_from_mapping(
        {"assembly": {"nodes": NODES, "centre_of_mass": "secondaries"}, "loads": {"gravity": gravity}},
        source="test",
    )
    assert massless_master.loads.moment_free
    assert reference_solution(free, np.linspace(0.0, 1.0, 3)).name == "exact_asymmetric"
    pinned = loaded({"gravity": gravity}, centre_of_mass="master")
    assert not pinned.loads.moment_free
    weights = {name: np.asarray(gravity) * node["mass"] for name, node in NODES.items()}
    run = simulate([pinned], "rk4", 1e-3, 0.1)
    turns, _ = independent_run(pinned, weights, run.time)
    assert np.max(orientation_error(run.quaternion[0], turns.as_quat())) < 1e-9


# The discrete Moser-Veselov step has no solution past h |w| = 1 about a principal axis (it
# turns a steady spin by asin(h w) a step; tests/test_published_steps.py).
NO_STEP_PAST_ONE = ("lgvi",)


def test_the_radioss_step_limit_is_a_flag_of_its_own():
    """A symmetric top spinning at |w| = 10 rad/s about its axis: dt |w| = 0.5 is within
    the OpenRadioss limit, dt |w| = 2 past it; the flag says so for every scheme, and the
    run goes on (its status is its own: a spin about a principal axis stays finite).
    dop853 takes its own steps, far smaller: within the limit at both output grids."""
    scene = scene_from_mapping(
        {
            "body": {"inertia": [1.0, 1.0, 2.0]},
            "initial": {"angular_velocity": {"body": [0.0, 0.0, 10.0]}},
            "duration": 2.0,
        },
        source="test",
    )
    for name in BUILTIN:
        within, past = (simulate([scene], name, dt, 0.2) for dt in (0.05, 0.2))
        assert within.results["radioss_dt_limit"][0] == 0, name
        if name in NO_STEP_PAST_ONE:
            assert past.status_names == ["not_converged"], name
            continue
        if SCHEMES[name].adaptive:
            assert 0.0 < past.results["max_step_angle"][0] < 0.5, name
            assert past.results["radioss_dt_limit"][0] == 0, name
            continue
        assert math.isclose(within.results["max_step_angle"][0], 0.5, rel_tol=1e-12)
        assert math.isclose(past.results["max_step_angle"][0], 2.0, rel_tol=1e-12)
        assert past.results["radioss_dt_limit"][0] == 1, name
        assert past.status_names == ["ok"] and past.results["n_steps"][0] == 10, name


def test_the_radioss_flag_follows_the_largest_spin_not_the_first():
    """Spun up about its axis by a constant axial moment from |w| = 5 to 15 rad/s at
    dt = 0.1 s: dt |w0| = 0.5, but the flag takes the largest |w| over the steps, dt |w| =
    1.5 at the end (every fixed-step scheme integrates the linear spin-up exactly)."""
    scene = scene_from_mapping(
        {
            "body": {"inertia": [1.0, 1.0, 2.0]},
            "initial": {"angular_velocity": {"body": [0.0, 0.0, 5.0]}},
            "loads": {"moment_body": [0.0, 0.0, 10.0]},
            "duration": 2.0,
        },
        source="test",
    )
    for name in FIXED_STEP:
        run = simulate([scene], name, 0.1, 0.2)
        if name in NO_STEP_PAST_ONE:  # spun past h |w| = 1
            assert run.status_names == ["not_converged"], name
            continue
        assert math.isclose(run.results["max_step_angle"][0], 1.5, rel_tol=1e-12), name
        assert run.results["radioss_dt_limit"][0] == 1, name


def test_leapfrog_grows_m_squared_by_dt2_m_cross_w_squared_each_step():
    """OpenRadioss's central difference on an assembled asymmetric body: the lagged
    gyroscopic term makes |m|^2 grow by dt^2 |m x w|^2 and twice the energy by
    dt^2 (m x w) . I^-1 (m x w) every step, exactly (to round-off), as the theory says."""
    scene = loaded({}, spin=(0.4, 1.1, -0.6), duration=5.0)
    dt = 0.01
    run = simulate([scene], "leapfrog", dt)
    inertia = np.array(scene.body.inertia)
    w = run.omega_body[0]
    m = inertia * w
    growth = np.diff(np.sum(m * m, axis=-1))
    predicted = dt**2 * np.sum(np.cross(m, w) ** 2, axis=-1)[:-1]
    assert np.all(growth > 0.0)
    assert np.allclose(growth, predicted, rtol=1e-9)
    twice_energy = np.diff(np.sum(m * w, axis=-1))
    cross = np.cross(m, w)[:-1]
    assert np.allclose(twice_energy, dt**2 * np.sum(cross * cross / inertia, axis=-1), rtol=1e-9)
    # and so the energy drift over the run is the sum of those steps, nothing else
    energy = 0.5 * np.sum(m * w, axis=-1)
    assert energy[-1] > energy[0] * (1.0 + 1e-4)


# --- node tables ------------------------------------------------------------------------------

TABLE = """# id x y z mass
id, x, y, z, mass
1, 1.0, 0.2, 0.0, 2.0
2, -0.8, 0.5, 0.1, 1.0

3, 0.1, -1.2, 0.3, 1.5
4, 0.2, 0.1, 0.9, 0.5
"""


def test_a_node_table_file_is_the_inline_nodes(tmp_path):
    """CSV with names and comments, or white space with nodal inertias: the same body as the
    inline nodes, read relative to the config."""
    (tmp_path / "nodes.csv").write_text(TABLE)
    spaced = "\n".join(
        " ".join(f"{v}" for v in [k, *n["position"], n["mass"], 0, 0, 0, 0, 0, 0]) for k, n in NODES.items()
    )
    (tmp_path / "nodes.txt").write_text(spaced + "\n")
    inline = loaded({})
    for name in ("nodes.csv", "nodes.txt"):
        table = scene_table(
            {
                "assembly": {"master": MASTER, "nodes": name},
                "initial": {"angular_velocity": {"space": [0.4, 1.1, -0.6]}},
                "duration": 2.0,
            },
            source=str(tmp_path / "study.yaml"),
        )
        scene = table.scene(0)
        assert scene.node_names == ("1", "2", "3", "4")
        assert scene.body.inertia == pytest.approx(inline.body.inertia, rel=1e-15)
        assert np.array_equal(scene.nodes, inline.nodes)
        assert len(table.tables) == 1


@pytest.mark.parametrize(
    "text, message",
    [
        ("1, 1, 0, 0\n", "nodes.csv: line 1: expected 5 or 11 columns"),
        ("1 1 0 0 1\n2 0 1 0 1 0 0 0 0 0 0\n", "nodes.csv: line 2: expected 5 columns"),
        ("1, 1, nan, 0, 1\n", "nodes.csv: line 1 (node 1): y = 'nan' is not a finite number"),
        ("1, 1, 0, 0, -2\n", "nodes.csv: line 1 (node 1): mass = -2.0 must be >= 0"),
        (
            "1, 1, 0, 0, 1\n# a comment\n1, 0, 1, 0, 1\n",
            "nodes.csv: line 3 (node 1): node 1 is given again (first on line 1)",
        ),
        ("1, 1, abc, 0, 1\n", "nodes.csv: line 1 (node 1): y = 'abc' is not a finite number"),
        ("master, 1, 0, 0, 1\n", "names the master node; rename this node"),
        ("id, x, z, y, mass\n", "nodes.csv: line 1: the column names"),
        ("# nothing\n", "nodes.csv: table: the node table has no nodes"),
    ],
)
def test_a_bad_node_table_names_its_file_and_line(tmp_path, text, message):
    (tmp_path / "nodes.csv").write_text(text)
    with pytest.raises(SceneError, match=message.replace("(", r"\(").replace(")", r"\)")):
        scene_table(
            {"assembly": {"master": MASTER, "nodes": "nodes.csv"}}, source=str(tmp_path / "study.yaml")
        )


def test_a_missing_node_table_is_named(tmp_path):
    with pytest.raises(SceneError, match="missing.csv: table: cannot read the node table: No such file"):
        scene_table({"assembly": {"nodes": "missing.csv"}}, source=str(tmp_path / "s.yaml"))


def test_a_study_sweeps_node_tables_and_radioss_options(tmp_path):
    """Two tables of the same node ids, the centre option and spherical inertia, swept like
    any value; the ids follow the tables' contents; tables of other ids are refused."""
    (tmp_path / "a.csv").write_text(TABLE)
    (tmp_path / "b.csv").write_text(TABLE.replace("0.5\n", "2.5\n"))
    scene = {
        "assembly": {"master": MASTER, "nodes": "a.csv"},
        "initial": {"angular_velocity": {"space": [0.0, 0.0, 1.0]}},
        "duration": 0.5,
    }
    sweep = {
        "scene.assembly.nodes": ["a.csv", "b.csv"],
        "scene.assembly.centre_of_mass": ["all", "master"],
        "scene.assembly.spherical": [False, True],
    }
    study = load_study(write_study(tmp_path, scene=scene, sweep=sweep))
    masses = [case.scene.body.mass for case in study.cases]
    assert masses == [6.0] * 4 + [8.0] * 4
    spherical = [case.scene.body.symmetry_axis is not None for case in study.cases]
    assert spherical == [False, True] * 4
    centres = [case.scene.position for case in study.cases]
    assert centres[2] == tuple(MASTER["position"]) != centres[0]  # pinned at the master
    first = {batch.id for batch in study.batches}
    (tmp_path / "b.csv").write_text(TABLE.replace("0.5\n", "3.5\n"))
    assert not first & {batch.id for batch in load_study(tmp_path / "study.yaml").batches}
    (tmp_path / "b.csv").write_text(TABLE.replace("\n4,", "\n5,"))
    with pytest.raises(
        InputError,
        match=r"sweep \(assembly_nodes\[1\] = 'b.csv'.*: the node "
        "tables a.csv and b.csv name different nodes",
    ):
        load_study(tmp_path / "study.yaml")


def test_a_spreadsheet_export_reads_as_the_table(tmp_path):
    """A byte-order mark, Windows line ends, column names in capitals, quoted ids and a
    trailing comma on every line: the same nodes as the plain table."""
    lines = ["ID,X,Y,Z,Mass,"] + [
        f'"{k}",{",".join(map(str, n["position"]))},{n["mass"]},' for k, n in NODES.items()
    ]
    (tmp_path / "export.csv").write_bytes(("\ufeff" + "\r\n".join(lines) + "\r\n").encode())
    (tmp_path / "plain.csv").write_text(TABLE)
    read = {
        name: scene_table(
            {"assembly": {"master": MASTER, "nodes": name}}, source=str(tmp_path / "study.yaml")
        ).scene(0)
        for name in ("export.csv", "plain.csv")
    }
    assert read["export.csv"].node_names == read["plain.csv"].node_names == ("1", "2", "3", "4")
    assert np.array_equal(read["export.csv"].nodes, read["plain.csv"].nodes)


def test_quoted_ids_keep_their_commas_and_a_quoted_header_names_the_columns(tmp_path):
    """Ids quoted as a spreadsheet quotes text, with a comma or a space inside, in a CSV table
    under a quoted header and in a table of white space: each id whole, the same body."""
    ids = ["left, front", "right, front", "3", "rear top"]
    rows = list(zip(ids, NODES.values(), strict=True))
    (tmp_path / "quoted.csv").write_text(
        '"id","x","y","z","mass"\n'
        + "".join(f'"{k}",{",".join(map(str, n["position"]))},{n["mass"]}\n' for k, n in rows)
    )
    (tmp_path / "quoted.txt").write_text(
        "".join(f'"{k}"\t{"  ".join(map(str, n["position"]))} {n["mass"]}\n' for k, n in rows)
    )
    plain = loaded({})
    for name in ("quoted.csv", "quoted.txt"):
        scene = scene_table(
            {
                "assembly": {"master": MASTER, "nodes": name},
                "initial": {"angular_velocity": {"space": [0.4, 1.1, -0.6]}},
                "duration": 2.0,
            },
            source=str(tmp_path / "study.yaml"),
        ).scene(0)
        assert scene.node_names == tuple(ids), name
        assert np.array_equal(scene.nodes, plain.nodes)


def test_the_archive_of_a_radioss_study(tmp_path):
    """A swept Radioss option is a coordinate of names ("false", "true"); every case says
    whether it passed the OpenRadioss limit and whether its inertia was regularised; the
    summary counts the cases past the limit, and the stability map is drawn."""
    scene = {
        "assembly": {"master": MASTER, "nodes": NODES},
        "initial": {"angular_velocity": {"space": [0.0, 0.0, 1.0]}},
        "duration": 0.4,
    }
    sweep = {
        "scheme": ["rk4", "midpoint"],
        "scene.assembly.spherical": [False, True],
        "spin": [5.0, 15.0],
    }  # dt |w0| = 0.5 and 1.5
    path = write_study(
        tmp_path, scene=scene, sweep=sweep, run={"scheme": "rk4", "dt": 0.1}, output={"interval": 0.1}
    )
    ds = open_results(run_study(load_study(path), tmp_path / "out", quiet=True).path)
    assert list(ds["assembly_spherical"].values) == ["false", "true"]
    assert ds["radioss_dt_limit"].attrs["flag_meanings"] == "within exceeded"
    assert (ds["radioss_dt_limit"].sel(spin=15.0) == 1).all()
    assert (ds["max_step_angle"].sel(spin=5.0) < 1.0).all()
    assert ds["regularised_inertia"].attrs["flag_meanings"] == "as_assembled regularised"
    assert (ds["regularised_inertia"] == 0).all()
    rows = scheme_rows(ds)
    assert [row["radioss"] for row in rows] == [2, 2]  # spin 15 rad/s, both bodies
    header = format_table(rows, wide=True, fmt="csv").splitlines()[0]
    assert "past Radioss limit" in header and "Radioss" not in format_table(rows)
    assert stability_map(ds, tmp_path / "figures").written
