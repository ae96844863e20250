"""Schemes from other packages (docs/extending.md): the example plug-in installed and swept,
the vectorised driver against the compiled one, and every way a plug-in can fail to load."""

import dataclasses
import importlib
import importlib.metadata
import os
import pathlib
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import xarray as xr
from helpers import (
    CONFIGS,
    HOSTILE,
    HOSTILE_SHOWN,
    LOADED,
    TERMINAL_CONTROLS,
    abaqus_mapping,
    listed_schemes,
    write_study,
)

from rbstudy.errors import InputError, SchemeError
from rbstudy.extending import make_batch_entry
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics.driver import run_batch
from rbstudy.numerics.sources import package_digest
from rbstudy.physics.scenes import param_rows
from rbstudy.pipeline.batches import plan_batches
from rbstudy.pipeline.config import load_study
from rbstudy.schemes import BUILTIN, SCHEMES, get_scheme, unavailable_schemes
from rbstudy.schemes._plugins import GROUP, load_plugins

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "semi_implicit"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The example plug-in installed by pip into a folder of its own (not into this
    environment, which the other tests share); the environment of a process that sees it."""
    target = tmp_path_factory.mktemp("site")
    # built from a copy: setuptools leaves build/ and *.egg-info in the folder it builds
    source = tmp_path_factory.mktemp("example") / "semi_implicit"
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--disable-pip-version-check",
            "--target",
            str(target),
            str(source),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), str(ROOT)])}


def _rbstudy(env, *args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "rbstudy", *args],
        env=env,
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.slow
def test_installed_example_is_listed_as_a_plugin(installed, tmp_path):
    listed = _rbstudy(installed, "schemes", cwd=tmp_path)
    assert listed.returncode == 0, listed.stderr
    lines = listed_schemes(listed.stdout)
    for name in ("semi_implicit", "semi_implicit_numpy"):
        assert "(plug-in: rbstudy-semi-implicit 0.1.0)" in lines[name]
    assert "plug-in" not in lines["euler"]


@pytest.mark.slow
def test_installed_example_sweeps_with_its_nominal_order(installed, tmp_path):
    """Both kinds of the example sweep like built-ins; they show order 1 on the Abaqus top,
    agree with each other to round-off, and the archive names where they come from."""
    swept = _rbstudy(
        installed,
        "sweep",
        str(EXAMPLE / "semi_implicit_top.yaml"),
        "--out",
        str(tmp_path),
        "--quiet",
        cwd=tmp_path,
    )
    assert swept.returncode == 0, swept.stderr
    archive = tmp_path / "semi_implicit_top" / "semi_implicit_top.nc"
    with xr.open_dataset(archive) as ds:
        assert (ds["status"] == 0).all()
        origin = dict(zip(ds["scheme"].values, ds["scheme_origin"].values, strict=True))
        assert origin["semi_implicit"] == "rbstudy-semi-implicit 0.1.0"
        assert origin["euler"] == "rbstudy"
        errors = ds["final_orientation_error"]
        dts = ds["dt"].values
        for scheme in ("semi_implicit", "semi_implicit_numpy"):
            assert int(ds["nominal_order"].sel(scheme=scheme)) == 1
            for ratio in ds["inertia_ratio"].values:
                error = errors.sel(scheme=scheme, inertia_ratio=ratio).values
                slope = np.polyfit(np.log(dts), np.log(error), 1)[0]
                assert abs(slope - 1.0) < 0.1, (scheme, ratio, slope)
        compiled, vectorised = (
            ds["quaternion"].sel(scheme=name).values for name in ("semi_implicit", "semi_implicit_numpy")
        )
        assert np.max(np.abs(compiled - vectorised)) < 1e-12
        # the vectorised kind is timed the same way, and is the slower
        assert (
            ds["run_time"].sel(scheme="semi_implicit_numpy") > ds["run_time"].sel(scheme="semi_implicit")
        ).all()


def _row_by_row(module):
    """A scheme's compiled ``init`` and ``step`` applied to each body in turn, as a
    vectorised scheme: the vectorised driver then sees the very arithmetic of the compiled
    one (the carry in ``work`` included)."""
    init = getattr(module, "init_inplace", None)

    def each_init(y, p, opt, t, h, work):
        return [init(y[b], p[b], opt[b], t, h, work[b]) for b in range(len(y))]

    def each_step(y, p, opt, t, h, work):
        done = [module.step_inplace(y[b], p[b], opt[b], t, h, work[b]) for b in range(len(y))]
        return [status for status, _ in done], [iterations for _, iterations in done]

    return make_batch_entry(each_step, each_init if init else None, module.N_WORK)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["euler", "hht"])
def test_vectorised_driver_books_like_the_compiled_driver(name):
    """Samples, statuses, failure times, step and iteration counts, drifts and step angles of
    every body, blow-ups included, equal those of the compiled driver, bit for bit; `hht`
    starts its carry in ``init`` and iterates Newton."""
    fast = {
        "body": {"mass": 1.0, "inertia": [1.0, 2.0, 3.0]},
        "initial": {"angular_velocity": {"body": [4.0, 0.3, 4.0]}},
        "duration": 10.0,
    }
    scenes = [
        scene_from_mapping(mapping, "test")
        for mapping in (
            {**abaqus_mapping(), "duration": 10.0},
            fast,
            {**LOADED, "duration": 10.0},
            {**fast, "initial": {"angular_velocity": {"body": [0.0, 0.0, 0.0]}}},
            {**fast, "initial": {"angular_velocity": {"body": [6.0, 0.1, 2.0]}}},
        )
    ]
    compiled = get_scheme(name)
    row_by_row = dataclasses.replace(
        compiled,
        name=f"{name}_rows",
        run_bodies_inplace=_row_by_row(importlib.import_module(f"rbstudy.schemes.{name}")),
    )
    dt = {"euler": 0.02, "hht": 1.0}[name]
    arguments = (
        np.array([scene.state_row() for scene in scenes]),
        param_rows(scenes),
        np.repeat(compiled.option_row()[None, :], len(scenes), axis=0),
        dt,
        500,
        3,
    )
    expected, got = run_batch(compiled, *arguments), run_batch(row_by_row, *arguments)
    statuses = expected.results["status"]
    assert 0 < np.count_nonzero(statuses) < len(scenes)  # blow-ups beside finished bodies
    np.testing.assert_array_equal(got.samples, expected.samples)
    for result, column in expected.results.items():
        np.testing.assert_array_equal(got.results[result], column, err_msg=result)


def _plugin_module(folder, name, text):
    (folder / f"{name}.py").write_text(textwrap.dedent(text))


@pytest.fixture
def fake_plugins(tmp_path, monkeypatch):
    """Register entry points (name -> "module:attribute") for a fresh registry."""
    monkeypatch.syspath_prepend(str(tmp_path))

    def register(points):
        entries = importlib.metadata.EntryPoints(
            importlib.metadata.EntryPoint(name, value, GROUP) for name, value in points.items()
        )
        monkeypatch.setattr(
            importlib.metadata, "entry_points", lambda group=None: entries if group == GROUP else ()
        )
        monkeypatch.setattr(SCHEMES, "_groups", {})  # loaded again on first use

    return tmp_path, register


def test_plugins_that_cannot_load_are_listed_with_the_fix(fake_plugins, capsys):
    folder, register = fake_plugins
    _plugin_module(
        folder,
        "engine_plugin",
        """
        from rbstudy.extending import SchemeUnavailable
        raise SchemeUnavailable("needs the mujoco package", 'pip install "rbstudy[engines]"')
        """,
    )
    _plugin_module(folder, "broken_plugin", "import a_module_nobody_has\n")
    _plugin_module(
        folder,
        "odd_plugin",
        """
        from rbstudy.schemes import BUILTIN
        NOT_A_SCHEME = 3
        EULER = BUILTIN["euler"]
        """,
    )
    register(
        {
            "engine_rk4": "engine_plugin:SCHEME",
            "broken": "broken_plugin:SCHEME",
            "odd": "odd_plugin:NOT_A_SCHEME",
            "renamed": "odd_plugin:EULER",
            "euler": "odd_plugin:EULER",
        }
    )
    missing = unavailable_schemes()
    assert set(missing) == {"engine_rk4", "broken", "odd", "renamed", "euler"}
    assert missing["engine_rk4"].fix == 'pip install "rbstudy[engines]"'
    assert "a_module_nobody_has" in missing["broken"].reason
    assert "not a Scheme" in missing["odd"].reason
    assert "is the scheme 'euler'" in missing["renamed"].reason
    assert "taken by rbstudy's own scheme" in missing["euler"].reason
    assert get_scheme("euler") is BUILTIN["euler"]  # the built-in keeps its name
    with pytest.raises(
        SchemeError,
        match=r"not available here: needs the mujoco package; "
        r'pip install "rbstudy\[engines\]"',
    ):
        get_scheme("engine_rk4")
    from rbstudy.cli import main

    assert main(["schemes"]) == 0
    listed = listed_schemes(capsys.readouterr().out)
    assert 'fix: pip install "rbstudy[engines]"' in listed["engine_rk4"]


def test_a_plugin_named_in_control_characters_is_listed_as_escapes(fake_plugins, capsys):
    """A plug-in's scheme name and its reason are another package's text: `rbstudy
    schemes` shows what a terminal would obey in them as escapes."""
    folder, register = fake_plugins
    _plugin_module(
        folder,
        "hostile_plugin",
        f"""
        from rbstudy.extending import SchemeUnavailable
        raise SchemeUnavailable({HOSTILE!r}, "reinstall it")
        """,
    )
    register({f"x{HOSTILE}": "hostile_plugin:SCHEME"})
    from rbstudy.cli import main

    assert main(["schemes"]) == 0
    listing = capsys.readouterr().out
    assert not TERMINAL_CONTROLS.search(listing), repr(listing)
    listed = " ".join(listing.split())
    assert f"x{HOSTILE_SHOWN} " in listed
    reason = HOSTILE_SHOWN.replace(r"\r", " ")  # wrapped as words: \r is a space between them
    assert f"unavailable {reason}; fix: reinstall it" in listed


def test_builtin_and_engine_names_import_no_plugin(fake_plugins):
    """A study of rbstudy's own schemes, or of MuJoCo's, never runs another package's code
    (before: the first reading of the registry imported every plug-in)."""
    folder, register = fake_plugins
    # a failed import leaves nothing in sys.modules, and the probe imports in a child: the
    # module's own mark, a file, tells whether any process ran it
    mark = folder / "never_plugin-ran"
    _plugin_module(
        folder,
        "never_plugin",
        f"import pathlib\npathlib.Path({str(mark)!r}).touch()\nraise SystemExit('imported')\n",
    )
    register({"never": "never_plugin:SCHEME"})
    assert get_scheme("euler") is BUILTIN["euler"]
    assert SCHEMES.find("mujoco_euler").name == "mujoco_euler"  # a Scheme, or Unavailable
    assert not mark.exists()
    assert "its import called sys.exit('imported')" in unavailable_schemes()["never"].reason
    assert mark.exists()  # listing every scheme does import it: the mark can tell


def test_a_config_naming_an_unavailable_scheme_fails_in_one_line(fake_plugins, tmp_path):
    folder, register = fake_plugins
    _plugin_module(
        folder,
        "engine_plugin2",
        """
        from rbstudy.extending import SchemeUnavailable
        raise SchemeUnavailable("needs the mujoco package", 'pip install "rbstudy[engines]"')
        """,
    )
    register({"engine_euler": "engine_plugin2:SCHEME"})
    config = tmp_path / "study.yaml"
    config.write_text(
        textwrap.dedent("""
        name: study
        scene: {body: {mass: 1.0, inertia: [1.0, 2.0, 3.0]}, duration: 0.1,
                initial: {angular_velocity: {body: [1.0, 0.0, 0.0]}}}
        output: {interval: 0.01}
        run: {scheme: engine_euler, dt: 0.01}
        """)
    )
    with pytest.raises(InputError) as raised:
        load_study(config)
    message = str(raised.value)
    assert "\n" not in message and "study.yaml" in message and "run.scheme" in message
    assert 'pip install "rbstudy[engines]"' in message


def test_a_working_plugin_joins_the_registry_but_not_scheme_all(fake_plugins):
    folder, register = fake_plugins
    (folder / "good_plugin").mkdir()
    _plugin_module(
        folder / "good_plugin",
        "__init__",
        """
        from dataclasses import replace
        from rbstudy.schemes import BUILTIN
        SCHEME = replace(BUILTIN["rk4"], name="my_rk4")
        """,
    )
    register({"my_rk4": "good_plugin:SCHEME"})
    found, missing = load_plugins(BUILTIN)
    assert missing == {} and found["my_rk4"].origin == "good_plugin:SCHEME"  # no distribution
    assert found["my_rk4"].code_digest == package_digest("good_plugin")
    assert "my_rk4" in SCHEMES and SCHEMES["my_rk4"].order == 4
    # `scheme: all` stays rbstudy's own: a config means the same whatever is installed
    config = write_study(folder, sweep={"scheme": "all"})
    assert "my_rk4" not in load_study(config).schemes
    assert "rk4" in load_study(config).schemes


def test_a_plugins_code_enters_its_batch_ids(tmp_path, monkeypatch):
    """Edited plug-in code never reuses the parts of the old; rbstudy's own schemes keep
    their ids."""
    package = tmp_path / "digest_plugin"
    package.mkdir()
    (package / "__init__.py").write_text("STEP = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    before = package_digest("digest_plugin.kernels")
    (package / "kernels.py").write_text("# a helper module of the plug-in\n")
    assert package_digest("digest_plugin.kernels") != before
    study = load_study(CONFIGS / "abaqus_top.yaml")
    plan = dict(
        cases=study.cases,
        scene=study.base["scene"],
        dimensions=study.dimensions,
        output_interval=study.output_interval,
        variables=study.variables,
        max_cases=64,
        verdict={"accuracy_bound": study.accuracy_bound},
    )
    plain = [batch.id for batch in plan_batches(**plan)]
    unchanged = [batch.id for batch in plan_batches(**plan, code_digests={"rk4": None})]
    assert unchanged == plain
    marked = plan_batches(**plan, code_digests={"rk4": before})
    changed = {batch.id for batch in marked if batch.scheme == "rk4"}
    assert changed.isdisjoint(plain) and len(changed) == sum(b.scheme == "rk4" for b in marked)
    again = plan_batches(**plan, code_digests={"rk4": package_digest("digest_plugin")})
    assert changed.isdisjoint(batch.id for batch in again)


def test_a_namespace_package_plugin_loads_with_a_digest(fake_plugins):
    folder, register = fake_plugins
    (folder / "spread" / "part").mkdir(parents=True)  # no __init__.py: a namespace package
    _plugin_module(
        folder / "spread" / "part",
        "mod",
        """
        from dataclasses import replace
        from rbstudy.schemes import BUILTIN
        SCHEME = replace(BUILTIN["rk4"], name="spread_rk4")
        """,
    )
    register({"spread_rk4": "spread.part.mod:SCHEME"})
    assert unavailable_schemes() == {}
    assert get_scheme("spread_rk4").code_digest == package_digest("spread.part.mod")


@pytest.mark.slow
def test_threads_reading_the_registry_first_wait_for_the_plugins(fake_plugins):
    """A second thread that reads the registry while the first is loading a slow plug-in
    finds the plug-in, not a registry of rbstudy's own schemes only."""
    import threading

    folder, register = fake_plugins
    _plugin_module(
        folder,
        "slow_plugin",
        """
        import time
        from dataclasses import replace
        from rbstudy.schemes import BUILTIN
        time.sleep(0.5)
        SCHEME = replace(BUILTIN["rk4"], name="slow_rk4")
        """,
    )
    register({"slow_rk4": "slow_plugin:SCHEME"})
    found = []
    readers = [threading.Thread(target=lambda: found.append(get_scheme("slow_rk4").name)) for _ in range(2)]
    for reader in readers:
        reader.start()
    for reader in readers:
        reader.join()
    assert found == ["slow_rk4", "slow_rk4"]


_EDITED_HELPER = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from edited_plugin import SCHEME
from rbstudy.numerics import state as S
from rbstudy.numerics.driver import run_batch
state = np.zeros((1, S.N_STATE))
state[0, S.QUATERNION + 3] = 1.0
params = np.zeros((1, S.N_PARAM))
params[0, S.MASS] = 1.0
params[0, S.INERTIA:S.INERTIA + 3] = 1.0
out = run_batch(SCHEME, state, params, np.zeros((1, S.N_OPTION)), 0.1, 1, 1)
print(out.samples[0, -1, S.POSITION])
"""


@pytest.mark.slow
def test_an_edited_helper_of_a_plugin_is_compiled_again(tmp_path):
    """numba checks only the file that defines a kernel: a plug-in's kernels are cached
    under a digest of its whole package, so a changed helper module is not run stale."""
    package = tmp_path / "edited_plugin"
    package.mkdir()
    (package / "__init__.py").write_text(
        textwrap.dedent("""
        from dataclasses import replace
        from rbstudy.extending import init_nothing, make_entry
        from rbstudy.schemes import BUILTIN
        from edited_plugin.kernel import step_inplace
        SCHEME = replace(BUILTIN["euler"], name="edited",
                         run_bodies_inplace=make_entry(step_inplace, init_nothing, 0))
        """)
    )
    (package / "kernel.py").write_text(
        textwrap.dedent("""
        from rbstudy.extending import OK, jit
        from edited_plugin.helper import shift
        @jit
        def step_inplace(y, p, opt, t, h, work):
            y[0] += shift()
            return OK, 0
        """)
    )
    helper = package / "helper.py"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    moved = []
    for value in (1.0, 2.0):
        helper.write_text(f"from rbstudy.extending import jit\n@jit\ndef shift():\n    return {value}\n")
        run = subprocess.run(
            [sys.executable, "-c", _EDITED_HELPER, str(tmp_path)],
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert run.returncode == 0, run.stderr
        moved.append(float(run.stdout))
    assert moved == [1.0, 2.0]
