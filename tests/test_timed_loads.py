"""Loads tabulated in time: read inline or from files, interpolated linearly inside the
kernels at the time of every stage, every scheme at its order, the references that apply."""

import numpy as np
import pytest
from helpers import FIXED_STEP, ROUND_OFF_FLOOR, independent_reference, write_study
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from rbstudy.errors import InputError, SceneError
from rbstudy.inputs.scenes import scene_from_mapping, scene_table
from rbstudy.numerics import state as S
from rbstudy.numerics.dynamics import body_moment, space_force
from rbstudy.physics.metrics import asymptotic_order, orientation_error
from rbstudy.physics.references import reference_solution
from rbstudy.physics.scenes import param_rows
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.schemes import SCHEMES, dop853

NODES = {"a": [0.5, 0.2, 0.1], "b": [-0.3, 0.4, -0.2]}
# Knots at multiples of 0.05 s, the coarsest step of the order test: no step straddles a kink.
PULL = [[0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 1.0, -2.0], [1.5, 2.0, 0.0, 0.0]]
TWIST = [[0.25, 0.0, 0.0, 0.0], [1.0, 0.6, -0.4, 1.2]]
PUSH = [[0.0, 1.0, 0.0, 0.0], [2.0, -1.0, 0.5, 0.0]]


def spec(loads, duration=2.0):
    """An asymmetric body with two nodes, tumbling, under ``loads``."""
    return {
        "body": {"mass": 2.0, "inertia": [1.0, 2.0, 3.0]},
        "initial": {
            "angular_velocity": {"body": [0.3, 1.0, 0.2]},
            "orientation": {"rotation_vector": [0.2, -0.1, 0.4]},
        },
        "nodes": NODES,
        "loads": loads,
        "duration": duration,
    }


LOADS = {
    "moment_body": {"table": TWIST},
    "nodes": {"a": {"force_space": {"table": PULL, "scale": 2.0}}, "b": {"force_body": {"table": PUSH}}},
}


def at(table, t, scale=1.0):
    """A table's value at ``t``: linear between rows, held outside them (numpy's own)."""
    table = np.asarray(table, dtype=float)
    return scale * np.array([np.interp(t, table[:, 0], table[:, k]) for k in (1, 2, 3)])


def loads_at(scene, turn, t):
    """Force in space and moment in body axes of `LOADS` at time ``t`` with the body turned by
    ``turn``, summed node by node in numpy from the tables."""
    offsets = dict(zip(scene.node_names, scene.nodes, strict=True))
    pull, push = at(PULL, t, 2.0), at(PUSH, t)
    force = pull + turn.apply(push)
    moment_body = (
        at(TWIST, t)
        + turn.inv().apply(np.cross(turn.apply(offsets["a"]), pull))
        + np.cross(offsets["b"], push)
    )
    return force, moment_body


def independent_run(scene, times):
    """The scene under `LOADS` by scipy's DOP853 on rotation matrices, the loads interpolated
    by numpy and summed node by node at every evaluation."""
    inertia, mass = np.array(scene.body.inertia), scene.body.mass

    def rates(t, y):
        turn, w, v = y[:9].reshape(3, 3), y[9:12], y[15:18]
        force, moment = loads_at(scene, Rotation.from_matrix(turn), t)
        skew = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        return np.concatenate(
            [(turn @ skew).ravel(), (moment - np.cross(w, inertia * w)) / inertia, v, force / mass]
        )

    start = np.concatenate(
        [
            Rotation.from_quat(scene.quaternion).as_matrix().ravel(),
            scene.omega_body,
            scene.position,
            scene.velocity,
        ]
    )
    solution = solve_ivp(
        rates, (0.0, times[-1]), start, method="DOP853", t_eval=times, rtol=1e-12, atol=1e-12, max_step=0.01
    )
    return Rotation.from_matrix(solution.y[:9].T.reshape(-1, 3, 3)), solution.y[12:15].T


def test_the_kernels_interpolate_the_tables_at_any_time_and_orientation():
    """Force and moment of the kernels against numpy's interpolation of each table and the
    sum r x F node by node: before the first knot, at knots, between, after the last."""
    scene = scene_from_mapping(spec(LOADS))
    p = scene.param_row()
    assert scene.loads.knots.tolist() == [0.0, 0.25, 0.5, 1.0, 1.5, 2.0]
    times = [-1.0, 0.0, 0.1, 0.25, 0.37, 0.5, 0.99, 1.0, 1.2, 1.5, 1.75, 2.0, 7.0]
    for t, turn in zip(times, Rotation.random(len(times), random_state=3), strict=True):
        force, moment = loads_at(scene, turn, t)
        assert np.allclose(body_moment(turn.as_quat(), np.zeros(3), p, t), moment, rtol=1e-13, atol=1e-13), t
        assert np.allclose(space_force(turn.as_quat(), p, t), force, rtol=1e-13, atol=1e-13), t


@pytest.mark.slow
def test_the_motion_under_tabulated_loads_is_euler_s_equations():
    """rk4 at a fine step, the reference and its DOP853 cross-check against an independent
    integration whose loads are interpolated and summed in numpy: the tables reach the
    kernels as written (the knots lie on the composed reference's steps)."""
    scene = scene_from_mapping(spec(LOADS))
    run = simulate([scene], "rk4", 1e-3, 0.1)
    turns, position = independent_run(scene, run.time)
    reference = reference_solution(scene, run.time)
    assert reference.name == "exact_split_composition"
    assert reference.uncertainty["orientation"] < 1e-11
    for quaternion, where in (
        (run.quaternion[0], run.position[0]),
        (reference.quaternion, reference.position),
    ):
        assert np.max(orientation_error(quaternion, turns.as_quat())) < 1e-9
        assert np.max(np.abs(where - position)) < 1e-9


@pytest.mark.parametrize("name", FIXED_STEP)
def test_tabulated_loads_keep_each_scheme_s_order(name):
    """A tabulated space force at a node (its moment turns with the body), a tabulated body
    force at another and a tabulated body moment: every scheme converges at its nominal
    order against the tight reference, when the knots lie on the steps."""
    scene = scene_from_mapping(spec(LOADS))
    dts = 0.05 / 2.0 ** np.arange(5)
    runs = [simulate([scene], name, dt, 0.5) for dt in dts]
    reference = independent_reference(scene, runs[0].time, name)
    errors = [orientation_error(r.quaternion[0, -1], reference.quaternion[-1]) for r in runs]
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    assert used.sum() >= 3 and abs(order - SCHEMES[name].order) <= 0.25, (order, errors)


def test_a_knot_inside_a_step_costs_rk4_its_order_and_the_study_says_so(tmp_path):
    """Knots off the steps: rk4 converges at order 2 only (the kink of the load inside a
    step), and a study of it warns, naming the knot; on the steps it does not warn."""
    off = {"moment_body": {"table": [[0.0, 0.0, 0.0, 0.0], [0.33, 0.0, 0.0, 2.0], [1.517, 1.0, 0.0, 2.0]]}}
    scene = scene_from_mapping(spec(off))
    dts = 0.05 / 2.0 ** np.arange(4)
    runs = [simulate([scene], "rk4", dt, 0.5) for dt in dts]
    reference = reference_solution(scene, runs[0].time)
    errors = [orientation_error(r.quaternion[0, -1], reference.quaternion[-1]) for r in runs]
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    assert used.sum() >= 3 and abs(order - 2.0) <= 0.25, (order, errors)
    study = load_study(
        write_study(
            tmp_path, scene=spec(off, 0.5), output={"interval": 0.1}, run={"scheme": "rk4", "dt": 0.02}
        )
    )
    assert study.warnings == (
        "scene.loads: the load tables' knot at t = 0.33 s falls inside a "
        "step of dt = 0.02 s: rk4 (order 4) converges at order 2 only "
        "across it; put the knots on multiples of dt",
    )
    assert (
        load_study(write_study(tmp_path, scene=spec(LOADS, 0.5), run={"scheme": "rk4", "dt": 0.01})).warnings
        == ()
    )


def test_a_ramped_axial_moment_is_integrated_exactly_by_rk4():
    """Spin about the z axis under a body moment along it that ramps up, holds and ramps
    down: w = w0 + (integral of M)/I3, a piecewise quadratic, and the angle its integral,
    a piecewise cubic. rk4 evaluates the moment at its stage times, so it integrates both
    exactly (to round-off) at a step that puts the knots on steps; stages all at the start
    of the step would be first order."""
    table = [[0.0, 0.0, 0.0, 0.0], [0.4, 0.0, 0.0, 3.0], [1.2, 0.0, 0.0, 3.0], [1.6, 0.0, 0.0, -1.0]]
    scene = scene_from_mapping(
        {
            "body": {"inertia": [1.0, 2.0, 3.0]},
            "initial": {"angular_velocity": {"body": [0.0, 0.0, 0.5]}},
            "loads": {"moment_body": {"table": table}},
            "duration": 2.0,
        }
    )
    run = simulate([scene], "rk4", 0.02, 0.02)
    fine = np.linspace(0.0, 2.0, 200_001)  # the closed form, by exact trapezoids of a line
    moment = np.interp(fine, *np.array(table)[:, [0, 3]].T)
    impulse = np.cumsum(np.diff(fine) * 0.5 * (moment[1:] + moment[:-1]))
    spin = 0.5 + np.concatenate([[0.0], impulse]) / 3.0
    assert np.allclose(run.omega_body[0, :, 2], np.interp(run.time, fine, spin), atol=1e-12)
    assert np.max(np.abs(run.omega_body[0, :, :2])) == 0.0
    # the angle at the end, from the exact integrals of each linear piece
    angle, w, clock = 0.0, 0.5, 0.0
    for (t0, *_, m0), (t1, *_, m1) in zip(table, table[1:] + [[2.0, 0, 0, -1.0]], strict=True):
        h, slope = t1 - t0, (m1 - m0) / (t1 - t0)
        angle += w * h + m0 * h**2 / 6.0 + slope * h**3 / 18.0
        w += (m0 * h + 0.5 * slope * h**2) / 3.0
        clock = t1
    assert clock == 2.0 and abs(w - run.omega_body[0, -1, 2]) < 1e-12
    turned = Rotation.from_quat(run.quaternion[0, -1]).as_rotvec()
    assert np.allclose(turned, [0.0, 0.0, (angle + np.pi) % (2 * np.pi) - np.pi], atol=1e-12)


def test_tabulated_gravity_and_forces_move_the_centre_of_mass_as_integrated():
    """A tabulated space force and tabulated gravity at the centre: v(t) is the integral of
    F/m + g, piecewise quadratic, which the second-order schemes' kicks get to round-off."""
    scene = scene_from_mapping(
        {
            "body": {"mass": 4.0, "inertia": [1.0, 1.0, 1.0]},
            "loads": {
                "force_space": {"table": [[0, 0, 0, 0], [1, 8, 0, 0]]},
                "gravity": {"table": [[0, 0, 0, -9.81], [1, 0, 0, 0]]},
            },
            "duration": 1.0,
        }
    )
    assert scene.loads.moment_free and scene.translates
    for name in ("midpoint", "splitting", "rk4"):
        run = simulate([scene], name, 0.01, 1.0)
        # v = integral of (2 t, 0, -9.81 (1 - t)) = (t^2, 0, -9.81 (t - t^2/2))
        assert np.allclose(run.velocity[0, -1], [1.0, 0.0, -9.81 / 2.0], atol=1e-12), name


def test_a_table_file_is_the_inline_table(tmp_path):
    """Column names, comments, commas or white space: the same table as inline."""
    (tmp_path / "pull.csv").write_text("# a pull\nt, x, y, z\n0, 0, 0, 0\n0.5, 0, 1, -2\n1.5,2,0,0\n")
    (tmp_path / "pull.txt").write_text("time x y z\n0 0 0 0\n0.5 0 1 -2\n\n1.5 2 0 0\n")
    read = [
        scene_table(
            spec({"nodes": {"a": {"force_space": {"table": table}}}}), source=str(tmp_path / "s.yaml")
        ).scene(0)
        for table in (PULL, "pull.csv", "pull.txt")
    ]
    assert read[0].param_row().tolist() == read[1].param_row().tolist() == read[2].param_row().tolist()


def test_a_quoted_table_is_the_table(tmp_path):
    """A spreadsheet's export: the header and every number quoted, a trailing comma; and
    quoted column names between spaces."""
    (tmp_path / "quoted.csv").write_text(
        '"t","x","y","z",\n' + "".join(",".join(f'"{value}"' for value in row) + ",\n" for row in PULL)
    )
    (tmp_path / "quoted.txt").write_text(
        '"time" "x" "y" "z"\n' + "".join(" ".join(map(str, row)) + "\n" for row in PULL)
    )
    read = [
        scene_table(
            spec({"nodes": {"a": {"force_space": {"table": table}}}}), source=str(tmp_path / "s.yaml")
        )
        .scene(0)
        .param_row()
        .tolist()
        for table in (PULL, "quoted.csv", "quoted.txt")
    ]
    assert read[0] == read[1] == read[2]


def test_a_line_csv_cannot_split_is_named(tmp_path):
    (tmp_path / "pull.csv").write_text("0, 0, 0, 0\n1, 0,\r 1, 0\n")  # a lone carriage return
    with pytest.raises(SceneError, match=r"pull.csv: line 2: cannot split the line into fields"):
        scene_table(
            spec({"nodes": {"a": {"force_space": {"table": "pull.csv"}}}}), source=str(tmp_path / "s.yaml")
        )


@pytest.mark.parametrize(
    "text, where, message",
    [
        ("0 0 0 0\n1 0 0 1\n1 0 0 2\n", "line 3", "time 1.0 does not come after 1.0"),
        ("0 0 0 0\n2 0 0 1\n1 0 0 2\n", "line 3", "time 1.0 does not come after 2.0"),
        ("0 0 0\n", "line 1", "expected 4 columns"),
        ("0 0 0 0\n1 0 nan 0\n", "line 2", "y = 'nan' is not a finite number"),
        ("# only a comment\n0 1 2 3\n", "table", "a load table needs two rows or more, got 1"),
    ],
)
def test_a_bad_table_file_names_its_line(tmp_path, text, where, message):
    (tmp_path / "bad.csv").write_text(text)
    with pytest.raises(SceneError, match=f"bad.csv: {where}: {message}"):
        scene_table(spec({"moment_space": {"table": "bad.csv"}}), source=str(tmp_path / "s.yaml"))


@pytest.mark.parametrize(
    "loads, key, message",
    [
        (
            {"moment_body": {"table": [[0, 0, 0, 0], [0, 1, 0, 0]]}},
            r"scene.loads.moment_body.table\[1\]",
            "time 0.0 does not come after 0.0",
        ),
        (
            {"moment_body": {"table": [[0, 0, 0]]}},
            r"scene.loads.moment_body.table\[0\]",
            "expected a list of 4 numbers",
        ),
        ({"moment_body": {"tabel": []}}, "scene.loads.moment_body.tabel", "unknown key"),
        ({"moment_body": {"scale": 2}}, "scene.loads.moment_body.table", "missing"),
        ({"moment_body": {"table": 3}}, "scene.loads.moment_body.table", "expected rows"),
        (
            {"nodes": {"a": {"force_body": {"table": [[0, 1, 2, 3]]}}}},
            "scene.loads.nodes.a.force_body.table",
            "a load table needs two rows or more",
        ),
        ({"moment_body": {"table": "nowhere.csv"}}, "nowhere.csv: table", "cannot read the load table"),
    ],
)
def test_a_bad_inline_table_names_its_key(tmp_path, loads, key, message):
    with pytest.raises(SceneError, match=f"{key}: {message}"):
        scene_table(spec(loads), source=str(tmp_path / "s.yaml"))


def test_a_study_sweeps_table_files_and_scales(tmp_path):
    """Table files of different knots and a scale, swept: each case takes its own table at
    the union of the knots; editing a table changes the batch ids; an inline entry swept is
    refused with the way to do it."""
    (tmp_path / "early.csv").write_text("0 0 0 0\n0.1 0 0 1\n")
    (tmp_path / "late.csv").write_text("0 0 0 0\n0.3 0 0 1\n0.4 0 0 0\n")
    scene = spec({"moment_body": {"table": "early.csv"}}, duration=0.5)
    sweep = {
        "scene.loads.moment_body.table": ["early.csv", "late.csv"],
        "scene.loads.moment_body.scale": [1.0, -3.0],
    }
    path = write_study(tmp_path, scene=scene, sweep=sweep, run={"scheme": "rk4", "dt": 0.01})
    study = load_study(path)
    loads = [case.scene.loads for case in study.cases]
    assert {tuple(load.knots) for load in loads} == {(0.0, 0.1, 0.3, 0.4)}
    ends = [np.asarray(load.tabulated)[-1, 9:12].tolist() for load in loads]  # moment_body
    assert ends == [[0, 0, 1], [0, 0, -3], [0, 0, 0], [0, 0, 0]]
    middles = [np.asarray(load.tabulated)[2, 11] for load in loads]  # at t = 0.3
    assert middles == [1.0, -3.0, 1.0, -3.0]
    first = {batch.id for batch in study.batches}
    (tmp_path / "late.csv").write_text("0 0 0 0\n0.3 0 0 2\n0.4 0 0 0\n")
    assert not first & {batch.id for batch in load_study(path).batches}
    inline = spec({"moment_body": {"table": PULL}}, duration=0.5)
    with pytest.raises(InputError, match="cannot be swept; write each table to a file"):
        load_study(
            write_study(tmp_path, scene=inline, sweep={"scene.loads.moment_body.table.1.3": [1.0, 2.0]})
        )
    with pytest.raises(InputError, match="sweep load tables by file name"):
        load_study(
            write_study(tmp_path, scene=inline, sweep={"scene.loads.moment_body.table": [PULL, TWIST]})
        )


def test_what_a_tabulated_load_changes_in_the_classification():
    """A tabulated force on a free symmetric top leaves it moment-free but takes it off its
    closed form (the centre of mass is no parabola); a tabulated moment makes it loaded;
    a table of zeros changes nothing."""
    top = {"body": {"inertia": [1.0, 1.0, 2.0]}, "initial": {"angular_velocity": {"body": [0.2, 0.0, 3.0]}}}
    pushed = scene_from_mapping({**top, "loads": {"force_space": {"table": PUSH}}})
    assert pushed.loads.moment_free and pushed.translates
    assert reference_solution(pushed, np.array([0.0, 0.5])).name == "exact_split_composition"
    twisted = scene_from_mapping({**top, "loads": {"moment_space": {"table": TWIST}}})
    assert not twisted.loads.moment_free
    zeros = scene_from_mapping({**top, "loads": {"moment_space": {"table": TWIST, "scale": 0.0}}})
    assert zeros.loads.moment_free and not zeros.translates and not zeros.loads.timed
    assert reference_solution(zeros, np.array([0.0, 0.5])).name == "symmetric_top"


def test_dop853_restarts_at_the_knots_inside_the_run():
    """The reference's runs end at each knot strictly inside (0, end), then at the end; a
    step budget spent at a knot leaves the run unfinished, never a sample past it."""
    p = scene_from_mapping(spec(LOADS)).param_row()
    assert dop853._segment_ends(p, 1.2) == [0.25, 0.5, 1.0, 1.2]
    assert dop853._segment_ends(p, 2.0) == [0.25, 0.5, 1.0, 1.5, 2.0]
    times = np.linspace(0.0, 2.0, 9)
    whole = dop853.integrate(scene_from_mapping(spec(LOADS)).state_row(), p, times)
    assert whole.finished and whole.reached == 2.0
    cut = dop853.integrate(scene_from_mapping(spec(LOADS)).state_row(), p, times, max_steps=whole.steps // 2)
    assert not cut.finished and cut.steps == whole.steps // 2
    done = np.isfinite(cut.samples[:, 0])
    assert np.array_equal(cut.samples[done], whole.samples[done])
    assert times[done][-1] <= cut.reached < 2.0


def test_tabulated_loads_equal_constant_ones_in_every_frame():
    """A table that holds one value is that constant load: the same moment and force at any
    time and orientation, for a body given by a full inertia tensor (body loads turned into
    its principal axes) and for an assembled body centred at its master, whose tabulated
    gravity has a lever."""
    tensor = {
        "body": {"mass": 2.0, "inertia": [[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 1.0]]},
        "nodes": NODES,
    }
    assembled = {
        "assembly": {
            "master": {"position": [0.3, 0.0, 0.1], "mass": 1.0},
            "nodes": {
                "a": {"position": [1.0, 0.2, 0.0], "mass": 2.0},
                "b": {"position": [-0.5, 0.6, 0.3], "mass": 1.0},
                "c": {"position": [0.1, -0.9, 0.4], "mass": 1.5},
            },
            "centre_of_mass": "master",
        }
    }
    constant = {
        "gravity": [0.0, -2.0, -9.81],
        "moment_body": [0.1, 0.2, 0.3],
        "nodes": {
            "a": {"force_body": [1.0, -1.0, 0.5], "force_space": [0.0, 3.0, -1.0]},
            "b": {"moment_space": [0.4, 0.0, -0.2]},
        },
    }

    def held(value):
        return {"table": [[0.0, *value], [1.0, *value]]}

    tabulated = {name: held(value) for name, value in constant.items() if name != "nodes"}
    tabulated["nodes"] = {
        node: {name: held(value) for name, value in loads.items()}
        for node, loads in constant["nodes"].items()
    }
    for body in (tensor, assembled):
        fixed = scene_from_mapping({**body, "loads": constant}).param_row()
        timed = scene_from_mapping({**body, "loads": tabulated}).param_row()
        for t, turn in zip((0.0, 0.4, 3.0), Rotation.random(3, random_state=5), strict=True):
            q = turn.as_quat()
            assert np.allclose(
                body_moment(q, np.zeros(3), timed, t),
                body_moment(q, np.zeros(3), fixed, t),
                rtol=1e-13,
                atol=1e-13,
            )
            assert np.allclose(space_force(q, timed, t), space_force(q, fixed, t), rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("name", FIXED_STEP)
def test_the_kernels_with_and_without_the_time_agree_on_constant_loads(name):
    """The two compiled variants of a scheme (numerics/clock.py) give the same bits for
    constant loads, in a batch mixed with rows of tabulated loads (wider rows)."""
    scheme = SCHEMES[name]
    loaded = scene_from_mapping(
        spec({"moment_space": [0.2, -0.1, 0.4], "nodes": {"a": {"force_space": [1.0, 0.0, -2.0]}}})
    )
    timed = scene_from_mapping(spec(LOADS))
    params = param_rows([loaded, timed])
    state0 = np.array([loaded.state_row(), timed.state_row()])
    options = np.repeat(scheme.option_row()[None], 2, axis=0)
    runs = {}
    for clock in (None, 0.0):
        scheme.ensure_compiled(timed=clock is not None)
        samples, results = np.empty((2, 11, S.N_STATE)), np.full((2, S.N_RESULT), np.nan)
        rows = (0, 1) if clock is None else (0, 2)  # without the time: the constant row only
        scheme.run_bodies_inplace(
            *rows,
            state0,
            params,
            options,
            0.01,
            50,
            5,
            0.5,
            samples,
            results,
            np.zeros(1, dtype=np.int64),
            clock,
        )
        runs[clock] = samples[0].copy(), results[0].copy()
    assert np.array_equal(runs[None][0], runs[0.0][0])
    assert np.array_equal(runs[None][1], runs[0.0][1], equal_nan=True)
