"""Plug-ins that misbehave (docs/extending.md): an import that hangs, exits or ends the
process, a `step_seconds` of NaN, a step that raises or returns a status that is no status
code. Each package is installed by pip into a folder of its own, as a user installs a
plug-in, and met through the command line; the compiled driver's check of the statuses is
met in this process."""

import dataclasses
import os
import pathlib
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import yaml
from helpers import abaqus_mapping, listed_schemes

from rbstudy.errors import RbstudyError
from rbstudy.numerics import state as S
from rbstudy.numerics.driver import run_batch
from rbstudy.schemes import BUILTIN
from rbstudy.schemes._plugins import Guarded

ROOT = pathlib.Path(__file__).resolve().parents[1]

# Each module of the first package marks that it was imported (a file in the working folder)
# before it misbehaves, so that a test can tell a plug-in was never imported.
_MARK = "import pathlib; pathlib.Path('imported-' + __name__).touch()\n"
BAD_IMPORTS = {
    "hangs": _MARK + "import time\ntime.sleep(1000)\n",
    "exits": _MARK + "import sys\nsys.exit(3)\n",
    "ends": _MARK + "import os\nos._exit(0)\n",
    "nan_cost": _MARK
    + textwrap.dedent("""
        from dataclasses import replace
        from rbstudy.schemes import BUILTIN
        SCHEME = replace(BUILTIN["euler"], name="nan_cost", step_seconds=float("nan"))
        """),
}
# The steps of the second package fail only on a spinning body, in a batch of a sweep;
# `raising` first waits (bounded) until a part of another batch is written, so that the
# sweep has a finished batch to keep, and is mended by STEP_MENDED.
_STEP = """
import glob, os, time
from dataclasses import replace
import numpy as np
from rbstudy.extending import OK, make_batch_entry, state as S
from rbstudy.schemes import BUILTIN

def step(y, p, opt, t, h, work):
    if os.environ.get("STEP_MENDED") or not np.any(y[:, S.OMEGA:S.OMEGA + 3]):
        return OK, 0
    FAIL

SCHEME = replace(BUILTIN["euler"], name=__name__.split(".")[-1],
                 run_bodies_inplace=make_batch_entry(step))
"""
BAD_STEPS = {
    "raising": _STEP.replace(
        "FAIL",
        textwrap.dedent("""
        deadline = time.monotonic() + 60
        while not glob.glob("out/*/parts/*.npz") and time.monotonic() < deadline:
            time.sleep(0.05)
        raise ValueError("the step cannot go on")""").replace("\n", "\n    "),
    ),
    "nan_status": _STEP.replace("FAIL", "return np.full(len(y), np.nan), 0"),
}


def _install(folder, project, modules):
    """pip-install the package ``project`` (a module per scheme, each its entry point) into
    a folder of its own; the environment of a process that sees it."""
    source = folder / "source"
    package = project.replace("-", "_")
    (source / package).mkdir(parents=True)
    (source / package / "__init__.py").write_text("")
    for name, text in modules.items():
        (source / package / f"{name}.py").write_text(text)
    points = "\n".join(f'{name} = "{package}.{name}:SCHEME"' for name in modules)
    (source / "pyproject.toml").write_text(
        textwrap.dedent(f"""
        [build-system]
        requires = ["setuptools>=61"]
        build-backend = "setuptools.build_meta"
        [project]
        name = "{project}"
        version = "0.1.0"
        [tool.setuptools]
        packages = ["{package}"]
        [project.entry-points."rbstudy.schemes"]
        """)
        + points
        + "\n"
    )
    target = folder / "site"
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


@pytest.fixture(scope="module")
def bad_imports(tmp_path_factory):
    return _install(tmp_path_factory.mktemp("imports"), "rbstudy-bad-imports", BAD_IMPORTS)


@pytest.fixture(scope="module")
def bad_steps(tmp_path_factory):
    return _install(tmp_path_factory.mktemp("steps"), "rbstudy-bad-steps", BAD_STEPS)


# `rbstudy schemes` with a short import bound, so that the hanging plug-in costs seconds;
# with another thread running when asked, so that the probe starts a fresh interpreter.
_SCHEMES = """
import sys, threading, time
import rbstudy.schemes._plugins as plugins
plugins.IMPORT_SECONDS, plugins.NOTICE_SECONDS = 4.0, 1.0
if sys.argv[1] == "threads":
    threading.Thread(target=time.sleep, args=(60,), daemon=True).start()
from rbstudy.cli import main
sys.exit(main(["schemes"]))
"""


def _run(env, *args, cwd, code=None):
    command = ["-c", code, *args] if code else ["-m", "rbstudy", *args]
    return subprocess.run(
        [sys.executable, *command], env=env, cwd=cwd, capture_output=True, text=True, timeout=300
    )


@pytest.mark.slow
@pytest.mark.parametrize("child", ["fork", "threads"])
def test_schemes_lists_plugins_that_hang_or_exit_as_unavailable(bad_imports, tmp_path, child):
    """Before: `schemes` hung on the first, and ended without a word (exit 3, or 0) on the
    others. Probed in a forked child, or in a fresh interpreter when threads run."""
    listed = _run(bad_imports, child, cwd=tmp_path, code=_SCHEMES)
    assert listed.returncode == 0, listed.stderr
    lines = listed_schemes(listed.stdout)
    assert "euler" in lines and "unavailable" not in lines["euler"]
    origin = "(rbstudy-bad-imports 0.1.0)"
    for name, reason in {
        "hangs": "its import did not finish within 4 s",
        "exits": "its import called sys.exit(3)",
        "ends": "its import ended the process (exit code 0)",
        "nan_cost": "step_seconds is nan",
    }.items():
        assert "unavailable" in lines[name] and reason in lines[name], lines[name]
        assert "fix: reinstall or fix rbstudy-bad-imports" in lines[name]
        assert lines[name].endswith(origin)
    assert "rbstudy: loading plug-in hangs from rbstudy-bad-imports..." in listed.stderr


def _study(folder, schemes):
    study = {
        "name": "faults",
        "scene": {**abaqus_mapping(), "duration": 0.1},
        "output": {"interval": 0.01},
        "run": {"scheme": schemes[0], "dt": 0.01},
        "sweep": {"scheme": schemes},
    }
    path = folder / "faults.yaml"
    path.write_text(yaml.safe_dump(study, sort_keys=False))
    return path


@pytest.mark.slow
def test_a_sweep_of_builtin_schemes_imports_no_plugin(bad_imports, tmp_path):
    """Before: the sweep hung on the plug-in that hangs, though it names none."""
    swept = _run(
        bad_imports, "sweep", str(_study(tmp_path, ["euler", "rk4"])), "--out", "out", "--quiet", cwd=tmp_path
    )
    assert swept.returncode == 0, swept.stderr
    assert (tmp_path / "out" / "faults" / "faults.nc").exists()
    assert not list(tmp_path.glob("imported-*")) and "plug-in" not in swept.stderr


@pytest.mark.slow
def test_a_plugin_step_that_raises_ends_the_sweep_in_one_line_and_keeps_finished_batches(bad_steps, tmp_path):
    """Before: exit 70, a traceback and "this is a bug in rbstudy"."""
    config = str(_study(tmp_path, ["euler", "raising"]))
    swept = _run(bad_steps, "sweep", config, "--out", "out", "--quiet", cwd=tmp_path)
    assert swept.returncode == 1, swept.stderr
    assert swept.stderr.splitlines() == [
        "rbstudy: error: scheme 'raising' (plug-in: rbstudy-bad-steps 0.1.0) failed: its step "
        "raised ValueError: the step cannot go on; fix or report it in rbstudy-bad-steps, or "
        "leave the scheme out"
    ]
    assert len(list((tmp_path / "out" / "faults" / "parts").glob("*.npz"))) == 1  # euler's
    resumed = _run(
        {**bad_steps, "STEP_MENDED": "1"}, "sweep", config, "--out", "out", "--quiet", cwd=tmp_path
    )
    assert resumed.returncode == 0, resumed.stderr
    assert "faults: 1 batch run, 1 reused" in resumed.stdout


@pytest.mark.slow
def test_a_plugin_step_that_returns_nan_as_status_ends_the_sweep_in_one_line(bad_steps, tmp_path):
    """Before: a traceback (NaN cast to an integer) with exit 70."""
    swept = _run(
        bad_steps, "sweep", str(_study(tmp_path, ["nan_status"])), "--out", "out", "--quiet", cwd=tmp_path
    )
    assert swept.returncode == 1, swept.stderr
    assert swept.stderr.splitlines() == [
        "rbstudy: error: scheme 'nan_status' (plug-in: rbstudy-bad-steps 0.1.0) failed: its "
        "step returned the status nan, which is not a status code: 0 (ok), 1 (unstable), "
        "2 (not_converged); fix or report it in rbstudy-bad-steps, or leave the scheme out"
    ]
    assert not (tmp_path / "out").exists()  # nothing finished: nothing left behind


def test_a_compiled_plugin_status_past_the_codes_is_the_plugins_fault():
    """A compiled entry point's statuses are checked after the call: 7 would be archived and
    read as no status at all. The plug-in is named; rbstudy's own schemes are not wrapped."""

    def seven(
        start,
        stop,
        state0,
        params,
        options,
        h,
        n_steps,
        every,
        drift_bound,
        samples,
        results,
        halt,
        clock=None,
    ):
        results[start:stop] = 0.0
        results[start:stop, S.Result.status] = 7

    scheme = dataclasses.replace(
        BUILTIN["euler"], name="seven", run_bodies_inplace=Guarded(seven, "seven", "pkg-seven 1.0")
    )
    state = np.zeros((2, S.N_STATE))
    state[:, S.QUATERNION + 3] = 1.0
    params = np.zeros((2, S.N_PARAM))
    params[:, S.MASS] = params[:, S.INERTIA : S.INERTIA + 3] = 1.0
    with pytest.raises(
        RbstudyError,
        match=r"^scheme 'seven' \(plug-in: pkg-seven 1.0\) failed: "
        r"its step returned the status 7.0, which is not a "
        r"status code: 0 \(ok\), .*in pkg-seven",
    ):
        run_batch(scheme, state, params, np.zeros((2, S.N_OPTION)), 0.1, 2, 1)
