"""Study configs and sweeps: values, product and zip, short names, dotted paths, batch ids,
and one-line errors for every bad input."""

import math

import numpy as np
import pytest
from helpers import write_study
from scipy.spatial.transform import Rotation

from rbstudy.errors import ConfigError
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.pipeline import estimate
from rbstudy.pipeline.config import load_study
from rbstudy.schemes import BUILTIN, SCHEMES, Scheme


def test_value_forms_expand_as_documented(tmp_path):
    study = load_study(
        write_study(
            tmp_path,
            sweep={
                "dt": {"halving": 0.01, "count": 4},
                "scene.body.mass": {"linspace": [1.0, 2.0, 3]},
                "spin": {"logspace": [1.0, 100.0, 3]},
            },
        )
    )
    values = {d.name: d.axes[0].values for d in study.dimensions}
    assert values["dt"] == (0.00125, 0.0025, 0.005, 0.01)  # ascending
    assert np.allclose(values["body_mass"], [1.0, 1.5, 2.0])
    assert np.allclose(values["spin"], [1.0, 10.0, 100.0])
    assert study.shape == (4, 3, 3) and len(study.cases) == 36
    case = study.cases[-1]  # C order: the last case takes the last value of every axis
    assert case.index == (3, 2, 2) and case.dt == 0.01 and case.scene.body.mass == 2.0
    assert math.isclose(np.linalg.norm(case.scene.omega_body), 100.0)


def test_all_means_every_fixed_step_scheme(tmp_path):
    study = load_study(write_study(tmp_path, sweep={"scheme": "all"}))
    own = tuple(name for name, s in BUILTIN.items() if not s.adaptive and s.group == "builtin")
    assert study.dimensions[0].axes[0].values == own
    assert "dop853" not in own and "lgvi" not in own  # the published steps: scheme: published


def test_a_list_of_schemes_takes_groups(tmp_path):
    """`all` and the groups of `bench --schemes` (builtin, engines, one per engine) stand for
    every scheme they name, installed or not (a config means the same study everywhere),
    each scheme once; without a group, a name given twice is still refused."""
    from rbstudy.schemes import unavailable_schemes
    from rbstudy.schemes._plugins import ENGINES

    own = tuple(name for name, s in BUILTIN.items() if not s.adaptive and s.group == "builtin")
    published = ("buss", "jolt", "lgvi", "simo_wong")
    cases = [
        (["rk4", "all"], ("rk4", *(name for name in own if name != "rk4"))),
        (["published", "midpoint"], (*published, "midpoint")),
    ]
    if not set(ENGINES) & set(unavailable_schemes()):  # CI installs the engines
        mujoco = tuple(name for name in ENGINES if name.startswith("mujoco_"))
        cases += [
            (["builtin", "engines"], (*own, *ENGINES)),
            (["mujoco", "mujoco_rk4", "euler"], (*mujoco, "euler")),
        ]
    for given, expected in cases:
        study = load_study(write_study(tmp_path, sweep={"scheme": given}))
        assert study.dimensions[0].axes[0].values == expected, given
    with pytest.raises(ConfigError, match="rk4 given twice"):
        load_study(write_study(tmp_path, sweep={"scheme": ["rk4", "rk4"]}))
    # an unknown name beside a group is named at its place in the config's list (it was
    # named at its place in the expanded one: scheme[9])
    with pytest.raises(ConfigError, match=r"sweep\.scheme\[2\]: unknown scheme 'bogus'"):
        load_study(write_study(tmp_path, sweep={"scheme": ["rk4", "builtin", "bogus"]}))


def test_zipped_axes_share_one_dimension(tmp_path):
    study = load_study(
        write_study(
            tmp_path,
            sweep={
                "dt": [0.01, 0.005],
                "zip": {"spin_tilt": {"spin": [1.0, 2.0, 4.0], "tilt": [0.0, 30.0, 60.0]}},
            },
        )
    )
    assert [d.name for d in study.dimensions] == ["dt", "spin_tilt"] and study.shape == (2, 3)
    for case in study.cases:
        spin, tilt = (1.0, 2.0, 4.0)[case.index[1]], (0.0, 30.0, 60.0)[case.index[1]]
        w = np.array(case.scene.omega_body)
        assert math.isclose(np.linalg.norm(w), spin, rel_tol=1e-14)
        assert math.isclose(math.degrees(math.atan2(math.hypot(w[0], w[1]), w[2])), tilt, abs_tol=1e-12)


def test_inertia_ratio_keeps_the_momentum_on_global_z(tmp_path):
    study = load_study(write_study(tmp_path, sweep={"inertia_ratio": [0.1, 0.5, 1.5, 2.0]}))
    for case, ratio in zip(study.cases, (0.1, 0.5, 1.5, 2.0), strict=True):
        assert case.scene.body.inertia == (1.0, 1.0, ratio)
        momentum = Rotation.from_quat(case.scene.quaternion).apply(
            np.array(case.scene.body.inertia) * case.scene.omega_body
        )
        assert np.allclose(momentum / np.linalg.norm(momentum), [0, 0, 1], atol=1e-14)


def test_scheme_options_apply_to_the_schemes_that_have_them(tmp_path):
    study = load_study(
        write_study(
            tmp_path,
            run={"scheme": "hht", "dt": 0.01},
            sweep={"scheme": ["rk4", "hht"], "run.options.alpha": [0.0, -0.1]},
        )
    )
    assert [d.name for d in study.dimensions] == ["scheme", "alpha"]
    options = {(c.scheme, c.index[1]): c.options for c in study.cases}
    assert options[("hht", 1)] == {"alpha": -0.1} and options[("rk4", 1)] == {}


@pytest.mark.parametrize("other", ["rk4", "mujoco_implicit", "bullet_rigidbody"])
def test_an_option_of_some_schemes_is_dropped_for_the_others_with_a_note(tmp_path, other):
    """The Abaqus top's run.options.alpha with an engine swept beside hht (issue 41): the
    engine runs without it, said in one note; hht's cases keep it, and the dimensions are
    those of the sweep."""
    if other != "rk4" and not isinstance(SCHEMES.find(other), Scheme):
        pytest.skip(f"{other} is not installed here")
    study = load_study(
        write_study(
            tmp_path,
            run={"scheme": "hht", "options": {"alpha": 0.0}, "dt": 0.01},
            sweep={"scheme": ["hht", other], "dt": [0.01, 0.005]},
        )
    )
    assert study.notes == ("run.options.alpha applies to hht only; the other schemes run without it",)
    assert [d.name for d in study.dimensions] == ["scheme", "dt"] and study.shape == (2, 2)
    assert {c.scheme: c.options for c in study.cases} == {"hht": {"alpha": 0.0}, other: {}}
    swept = load_study(
        write_study(
            tmp_path, name="swept", sweep={"scheme": ["hht", other], "run.options.alpha": [0.0, -0.1]}
        )
    )
    assert [d.name for d in swept.dimensions] == ["scheme", "alpha"] and len(swept.notes) == 1
    assert [c.options for c in swept.cases if c.scheme == "hht"] == [{"alpha": 0.0}, {"alpha": -0.1}]
    alone = load_study(
        write_study(tmp_path, name="alone", run={"scheme": "hht", "options": {"alpha": -0.1}, "dt": 0.01})
    )
    assert alone.notes == ()  # every scheme of the study takes it


def test_an_option_no_scheme_of_the_study_takes_is_refused_with_the_fix(tmp_path):
    path = write_study(tmp_path, run={"scheme": "rk4", "options": {"alpha": 0.0}, "dt": 0.01})
    with pytest.raises(ConfigError) as error:
        load_study(path)
    assert str(error.value) == (
        f"{path}: run.options.alpha: alpha is an option of none of the study's schemes (rk4); "
        "remove it (or --set 'run.options={}'), or sweep a scheme that takes it (hht)"
    )
    path = write_study(tmp_path, run={"scheme": "rk4", "options": {"alpah": 0.0}, "dt": 0.01})
    with pytest.raises(ConfigError, match="; remove it .* `rbstudy schemes` lists each scheme's options$"):
        load_study(path)


def test_a_missing_name_says_how_to_give_one(tmp_path):
    path = write_study(tmp_path)
    path.write_text("\n".join(line for line in path.read_text().splitlines() if not line.startswith("name:")))
    with pytest.raises(ConfigError) as error:
        load_study(path)
    assert str(error.value).startswith(f"{path}: name: missing; add name: <letters, digits, '-' and '_' only")


def test_a_group_alone_sweeps_its_schemes(tmp_path):
    study = load_study(write_study(tmp_path, sweep={"scheme": "builtin"}))
    assert [c.scheme for c in study.cases] == [
        name for name, s in BUILTIN.items() if not s.adaptive and s.group == "builtin"
    ]


def test_batches_group_scheme_and_dt_and_ids_are_stable(tmp_path):
    sweep = {"scheme": ["rk4", "euler"], "dt": [0.01, 0.005], "inertia_ratio": [0.5, 2.0]}
    first = load_study(write_study(tmp_path, sweep=sweep))
    assert len(first.batches) == 4
    for batch in first.batches:
        assert {(first.cases[i].scheme, first.cases[i].dt) for i in batch.cases} == {(batch.scheme, batch.dt)}
    again = load_study(
        write_study(tmp_path, name="study", sweep={**sweep, "inertia_ratio": [0.5, 2]})
    )  # 2 and 2.0 are the same case
    assert [b.id for b in again.batches] == [b.id for b in first.batches]
    changed = load_study(write_study(tmp_path, sweep={**sweep, "inertia_ratio": [0.5, 1.9]}))
    assert not {b.id for b in changed.batches} & {b.id for b in first.batches}
    # the same cases at other places of the grid are other batches: a reordered axis must
    # never put an old part in new cells
    reordered = load_study(write_study(tmp_path, sweep={**sweep, "inertia_ratio": [2.0, 0.5]}))
    assert not {b.id for b in reordered.batches} & {b.id for b in first.batches}
    # dt is stored ascending whatever order it is given in: the same study
    steps = load_study(write_study(tmp_path, sweep={**sweep, "dt": [0.005, 0.01]}))
    assert [b.id for b in steps.batches] == [b.id for b in first.batches]


# A body given by a full inertia tensor (principal axes not the input axes), its momentum
# along a tilted space axis and a body moment: every frame change a scene makes.
_TURNED_BODY = {
    "body": {"mass": 1.0, "inertia": [[2.0, 0.1, 0.0], [0.1, 1.5, 0.0], [0.0, 0.0, 1.0]]},
    "initial": {
        "angular_velocity": {"body": [0.3, 0.0, 2.0]},
        "orientation": {"momentum_axis": [0.0, 1.0, 1.0]},
    },
    "loads": {"moment_body": [0.0, 0.0, 0.0]},
    "nodes": {"tip": [0.1, 0.2, 0.3]},
    "duration": 0.5,
}


def test_the_scenes_of_a_sweep_are_each_case_read_alone(tmp_path):
    """The sweep reads its scenes as columns, all at once; each must be the scene its case's
    own mapping gives, and the physics of the short names must hold in it."""
    study = load_study(
        write_study(
            tmp_path,
            scene=_TURNED_BODY,
            sweep={
                "scheme": ["rk4", "leapfrog"],
                "scene.body.inertia.0.0": [2.0, 2.2],
                "scene.loads.moment_body.2": [0.0, 0.5],
                "zip": {"spin_tilt": {"spin": [1.0, 3.0], "tilt": [10.0, 40.0]}},
            },
        )
    )
    assert len(study.cases) == 16 and len(study.cases.scenes) == 8  # the schemes share them
    for case in study.cases:
        _, entry, moment, pair = case.index
        spin, tilt = (1.0, 3.0)[pair], math.radians((10.0, 40.0)[pair])
        alone = {
            **_TURNED_BODY,
            "body": {
                "mass": 1.0,
                "inertia": [[(2.0, 2.2)[entry], 0.1, 0.0], [0.1, 1.5, 0.0], [0.0, 0.0, 1.0]],
            },
            "initial": {
                "angular_velocity": {"body": [spin * math.sin(tilt), 0.0, spin * math.cos(tilt)]},
                "orientation": {"momentum_axis": [0.0, 1.0, 1.0]},
            },
            "loads": {"moment_body": [0.0, 0.0, (0.0, 0.5)[moment]]},
        }
        expected = scene_from_mapping(alone)
        for field in ("quaternion", "omega_body"):
            assert np.allclose(getattr(case.scene, field), getattr(expected, field), rtol=0.0, atol=1e-14), (
                field
            )
        assert case.scene.body.inertia == pytest.approx(expected.body.inertia, rel=1e-15)
        assert np.allclose(case.scene.loads.moment_body, expected.loads.moment_body, rtol=0.0, atol=1e-15)
        w = np.array(case.scene.omega_body)
        assert math.isclose(np.linalg.norm(w), spin, rel_tol=1e-14)
        space_momentum = Rotation.from_quat(case.scene.quaternion).apply(
            np.array(case.scene.body.inertia) * w
        )
        assert np.allclose(
            space_momentum / np.linalg.norm(space_momentum), [0.0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-14
        )
        assert math.isclose(np.linalg.norm(case.scene.loads.moment_body), (0.0, 0.5)[moment], abs_tol=1e-15)
        # what no frame changes, worked out in the input frame with the tensor itself: the
        # energy, and the node's distance and angle to the angular momentum
        tensor = np.array(alone["body"]["inertia"])
        w_input = np.array(alone["initial"]["angular_velocity"]["body"])
        node_input = np.array(_TURNED_BODY["nodes"]["tip"])
        assert math.isclose(
            0.5 * w @ (np.array(case.scene.body.inertia) * w), 0.5 * w_input @ tensor @ w_input, rel_tol=1e-13
        )
        node = np.array(case.scene.nodes[0])
        momentum = np.array(case.scene.body.inertia) * w
        assert math.isclose(np.linalg.norm(node), np.linalg.norm(node_input), rel_tol=1e-14)
        assert math.isclose(node @ momentum, node_input @ tensor @ w_input, rel_tol=1e-12)


@pytest.mark.parametrize(
    "sweep, scene, where, message",
    [
        # the scene's own check (the energy of the third spin overflows)
        (
            {"spin": [1.0, 2.0, 1.0e200], "scene.body.mass": [1.0, 2.0]},
            None,
            "spin[2] = 1e+200, body_mass[0] = 1.0",
            "scene.initial.angular_velocity.body: so large that the body's energy overflows a float; "
            "give a smaller angular velocity",
        ),
        # the reader's check of a column
        (
            {"spin": [1.0, 2.0], "scene.body.mass": [1, 2, -3]},
            None,
            "spin[0] = 1.0, body_mass[2] = -3",
            "scene.body.mass: must be > 0, got -3.0",
        ),
        # a short name's own check, its value as given
        (
            {"spin": [1.0, 0.0]},
            None,
            "spin[1] = 0.0",
            "spin must be > 0 rad/s, got 0.0; a body at rest has no rotation to study",
        ),
        # a swept entry of the vector a short name rewrites
        (
            {"scene.body.inertia.0": [1.0, 1.2], "inertia_ratio": [1.5, 2.0]},
            {
                "body": {"inertia": [1.0, 1.0, 2.0]},
                "initial": {"angular_velocity": {"body": [0.1, 0.0, 1.0]}},
                "duration": 0.5,
            },
            "body_inertia_0[1] = 1.2, inertia_ratio[0] = 1.5",
            "scene.body.inertia: inertia_ratio needs a body symmetric about axis 3, got "
            "[1.2, 1.0, 2.0]; give inertia: [I1, I1, I3]",
        ),
        (
            {"scene.initial.angular_velocity.body.0": [1.0, "a"], "spin": [1.0]},
            None,
            "initial_angular_velocity_body_0[1] = 'a', spin[0] = 1.0",
            "scene.initial.angular_velocity.body: expected a list of 3 finite numbers, got "
            "['a', 0.0, 6.283185307179586]",
        ),
    ],
)
def test_a_bad_value_inside_a_column_names_its_own_case(tmp_path, sweep, scene, where, message):
    """Scenes are checked as columns: the error names the values of the scene axes of the
    row that fails, not the first case of the grid, and shows that row's value as given;
    the scheme, which does not make the scene, is left out."""
    path = write_study(tmp_path, scene=scene, sweep={"scheme": ["rk4", "euler"], **sweep})
    with pytest.raises(ConfigError) as error:
        load_study(path)
    assert str(error.value).startswith(f"{path}: sweep ({where}): {message}"), error.value


@pytest.mark.parametrize(
    "sweep, message",
    [
        ({"speed": [1.0]}, "sweep.speed: unknown sweep axis 'speed'; use a short name"),
        ({"dt": []}, "sweep.dt: empty sweep; give at least one value"),
        (
            {"dt": [0.01, 0.003]},
            "sweep (dt[0] = 0.003): run.dt: dt = 0.003 s does not divide the "
            "output interval 0.01 s (0.01 / 0.003 = 3.33333); choose dt = 0.01 / n",
        ),
        (
            {"inertia_ratio": [2.0, 3.0]},
            "sweep (inertia_ratio[1] = 3.0): scene.body.inertia: "
            "[1.0, 1.0, 3.0] violates the triangle inequality",
        ),
        (
            {"scheme": ["rk4", "rk5"]},
            "sweep.scheme[1]: unknown scheme 'rk5'; valid schemes: buss, dop853, euler",
        ),
        (
            {"zip": {"pair": {"spin": [1.0], "tilt": [1.0, 2.0]}}},
            "sweep.zip.pair: zipped axes need equal lengths",
        ),
        ({"scene.duration": [1.0, 2.0]}, "sweep.scene.duration: scene.duration cannot be swept"),
        ({"dt": {"halving": 0.01}}, "sweep.dt: expected a list of values"),
        (
            {"run.options.alpha": [0.0]},
            "sweep.run.options.alpha: alpha is an option of none of the study's schemes (rk4); "
            "remove it, or sweep a scheme that takes it (hht)",
        ),
        ({"scene.body.mass": [1.0, -1.0]}, "sweep (body_mass[1] = -1.0): scene.body.mass: must be > 0"),
        (
            {"zip": {"time": {"spin": [1.0, 2.0]}}},
            "sweep.zip.time: 'time' is a name the dataset already uses",
        ),
        (
            {"zip": {"pair": {"scheme": ["rk4", "euler"], "spin": [1.0, 2.0]}}},
            "sweep.zip.pair.scheme: scheme cannot be zipped",
        ),
        (
            {"scene.body.inertia": [[1, 1, 2], [1, 1, 1.5]]},
            "sweep.scene.body.inertia[0]: sweep values must be numbers, names or true/false",
        ),
        ({"scheme": ["rk4", "rk4"]}, "sweep.scheme: rk4 given twice"),
        ({"scene.body.mass": [1, 1.0]}, "sweep.scene.body.mass: 1.0 given twice"),
        (
            {"scene.initial.angular_velocity.body.x": [1.0]},
            "scene.initial.angular_velocity.body.x: 'x' is not an entry of a list of 3; use 0..2",
        ),
        (
            {"spin": {"linspace": [1, 2, 1000]}, "tilt": {"linspace": [0, 60, 1001]}},
            "sweep: 1,001,000 cases (1000 x 1001); at most 1,000,000 per study",
        ),
    ],
)
def test_bad_sweeps_name_file_key_value_and_fix(tmp_path, sweep, message):
    path = write_study(tmp_path, sweep=sweep)
    with pytest.raises(ConfigError) as error:
        load_study(path)
    assert str(error.value).startswith(f"{path}: ") and message in str(error.value), error.value


def test_unknown_output_variable_and_one_a_scene_lacks(tmp_path):
    with pytest.raises(ConfigError, match=r"output.variables\[1\]: unknown variable 'omega'"):
        load_study(write_study(tmp_path, output={"interval": 0.01, "variables": ["quaternion", "omega"]}))
    with pytest.raises(ConfigError, match=r"output.variables\[0\]: position needs translation"):
        load_study(write_study(tmp_path, output={"interval": 0.01, "variables": ["position"]}))


def test_output_variables_narrow_trajectories_but_keep_the_bookkeeping(tmp_path):
    study = load_study(write_study(tmp_path, output={"interval": 0.01, "variables": ["quaternion"]}))
    assert "quaternion" in study.variables and "omega_body" not in study.variables
    assert {"status", "run_time", "n_steps", "initial_spin", "step_seconds"} <= set(study.variables)


def test_the_memory_forecast_counts_the_values_held_for_the_archive(tmp_path, monkeypatch):
    """A local run hands the archive's writer its values (at most writer.HELD_BYTES): the
    forecast counts them, up to the archive's uncompressed size."""
    from rbstudy.archive import writer

    study = load_study(write_study(tmp_path, sweep={"dt": {"halving": 0.01, "count": 4}}))
    monkeypatch.setattr(writer, "HELD_BYTES", 0)
    without = estimate.estimate(study).peak_bytes
    monkeypatch.setattr(writer, "HELD_BYTES", 2**40)  # more than the study holds: all of it
    whole = estimate.estimate(study)
    assert whole.peak_bytes - without == whole.archive_bytes > 0
    monkeypatch.setattr(writer, "HELD_BYTES", 1000)
    assert estimate.estimate(study).peak_bytes - without == 1000


def test_a_sweep_too_large_for_memory_is_refused_with_its_size(tmp_path, monkeypatch):
    path = write_study(tmp_path, sweep={"dt": {"halving": 0.01, "count": 4}})
    study = load_study(path)
    cost = estimate.estimate(study)
    # a machine with just enough memory takes it; one byte less is refused, size shown
    monkeypatch.setattr(estimate, "physical_memory", lambda: 2 * cost.peak_bytes)
    estimate.check_limits(study, cost)
    monkeypatch.setattr(estimate, "physical_memory", lambda: 2 * cost.peak_bytes - 2)
    with pytest.raises(
        ConfigError,
        match=r"sweep: needs about [\d,]+ MiB of memory at once "
        r"\(limit [\d,]+ MiB, half of this machine's\)",
    ):
        estimate.check_limits(study, cost)


def test_numbers_with_bare_exponents_are_numbers(tmp_path):
    path = write_study(tmp_path, output={"interval": 0.01})
    path.write_text(
        path.read_text().replace("dt: 0.01", "dt: 1e-3").replace("duration: 0.5", "duration: 5.0e-1")
    )
    study = load_study(path)
    assert study.cases[0].dt == 1e-3 and study.duration == 0.5


@pytest.mark.parametrize(
    "axis, message",
    [
        (
            "inertia_ratio",
            "sweep: scene.body.inertia: inertia_ratio needs a body symmetric about axis 3, got None",
        ),
        ("spin", "sweep: scene.initial.angular_velocity: spin needs the initial angular velocity"),
    ],
)
def test_a_short_name_over_a_malformed_scene_is_one_line(tmp_path, axis, message):
    """A body or initial state that is not a mapping: the short name says what it needs (it
    used to end in an AttributeError), under the sweep but naming no value of it (every
    value fails alike)."""
    path = write_study(tmp_path, scene={"body": [1, 2], "initial": 5, "duration": 0.5}, sweep={axis: [1.5]})
    with pytest.raises(ConfigError) as error:
        load_study(path)
    assert str(error.value).startswith(f"{path}: {message}"), error.value
