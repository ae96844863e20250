"""What the tests share that is not a fixture: scenes, configs, constants and helpers,
imported by name (``from helpers import write_study``); the fixtures are in conftest.py,
which no test imports."""

import math
import pathlib
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import yaml

from rbstudy.physics.analytic import INTEGRATED
from rbstudy.physics.metrics import orientation_error
from rbstudy.physics.references import REFERENCE_SCHEME, dop853_reference, reference_solution
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import BUILTIN

# Schemes with a fixed step, whose order in dt is observable (dop853 chooses its own steps).
FIXED_STEP = [name for name, scheme in BUILTIN.items() if not scheme.adaptive]

# Schemes that integrate a free body exactly at any step: on one, their error is round-off
# at every dt, with no order to observe (their order shows under loads).
EXACT_FOR_FREE_BODIES = ("exact_split",)
# What "round-off" means for them over the shipped and test runs: each step rounds the state,
# ~1.5e-16 rad a step (measured 1.6e-14 rad after 5 steps, 2.8e-13 after 3,200, 9.8e-13
# after 6,400 in the default study)
EXACT_FLOW_TOLERANCE = 2e-12

# Errors at or below this are round-off (the references are good to ~1e-13), never fitted.
ROUND_OFF_FLOOR = 1e-11


# A body under every kind of constant load: moments in body and space axes, a body-fixed
# force off no centre, and gravity.
LOADED = {
    "body": {"mass": 2.0, "inertia": [1.0, 2.0, 3.0]},
    "initial": {"angular_velocity": {"body": [0.6, 1.5, 0.9]}, "velocity": [1.0, 0.0, 0.5]},
    "loads": {
        "moment_body": [0.2, -0.1, 0.3],
        "moment_space": [0.0, 0.15, 0.0],
        "force_body": [0.5, 0.0, 0.0],
        "gravity": [0.0, 0.0, -9.81],
    },
    "duration": 2.0,
}


def abaqus_mapping(**body):
    """The Abaqus force-free top of docs/theory.md s2: I = (1, 1, 2), A = 0.25, w3 = 2 pi."""
    return {
        "body": {"mass": 1.0, "inertia": [1.0, 1.0, 2.0], **body},
        "initial": {
            "angular_velocity": {"body": [0.25, 0.0, 2.0 * math.pi]},
            "orientation": {"momentum_axis": [0.0, 0.0, 1.0]},
        },
        "nodes": {"2": [1.0, 0.0, 0.0], "3": [0.0, 1.0, 0.0], "4": [0.0, 0.0, 1.0]},
        "duration": 2.0,
    }


CONFIGS = pathlib.Path(__file__).resolve().parents[1] / "configs"
PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "rbstudy"


# How many times `parsed` tries: CPython 3.11 before 3.11.8 counts the AST constructor's
# depth in state shared by every thread, and raises a spurious SystemError ("AST
# constructor recursion depth mismatch", CPython issue gh-106905) when another thread (a
# dask worker an earlier test left running) builds an AST at the same moment.
PARSE_TRIES = 3


def parsed(source):
    """``ast.parse(source)``, tried again where CPython's spurious depth mismatch struck."""
    import ast

    for attempt in range(PARSE_TRIES):
        try:
            return ast.parse(source)
        except SystemError as error:
            if "recursion depth mismatch" not in str(error) or attempt == PARSE_TRIES - 1:
                raise
    raise AssertionError("unreachable")


def in_every_module(check):
    """What ``check(path, label)`` finds in each module of rbstudy (a list per module), one
    list; ``label`` the module's path in the package."""
    return [
        entry
        for path in sorted(PACKAGE.rglob("*.py"))
        for entry in check(path, str(path.relative_to(PACKAGE)))
    ]


# Text a hostile file may hold: ESC sequences that set the window's title (ended by BEL)
# and clear the screen, a C1 CSI, a carriage return and DEL; and how rbstudy shows it.
HOSTILE = "\x1b]0;pwned\x07\x1b[2J\x9b31m\rx\x7f"
HOSTILE_SHOWN = r"\x1b]0;pwned\x07\x1b[2J\x9b31m\rx\x7f"
# What a terminal obeys rather than shows: the C0 controls but newline and tab, DEL, C1.
TERMINAL_CONTROLS = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def listed_schemes(listing):
    """The rows of `rbstudy schemes`'s ``listing`` by scheme name, each row's wrapped lines
    joined into one."""
    rows, name = {}, None
    for line in listing.splitlines()[1:]:
        if not line:  # the groups follow the schemes
            break
        if line.startswith(" "):  # a summary wrapped under its column
            rows[name] += " " + line.strip()
        else:
            name = line.split()[0]
            rows[name] = line
    return rows


def copy_node_tables(folder):
    """Copy the node tables the shipped configs name into ``folder``, where copies of those
    configs are written (a table's path is relative to its config)."""
    for table in CONFIGS.glob("*.csv"):
        shutil.copy(table, folder)


# References computed by the code of `REFERENCE_SCHEME` (exact_split): its exact free flow,
# and its composition under loads.
SHARING_EXACT_SPLIT = ("exact_asymmetric", INTEGRATED)


def independent_reference(scene, times, scheme):
    """The scene's reference at ``times``, never computed by ``scheme``'s own code: for
    `REFERENCE_SCHEME`, whose free flow is that of the exact asymmetric reference and whose
    composition is the loaded body's, DOP853 instead."""
    reference = reference_solution(scene, times)
    if reference.name in SHARING_EXACT_SPLIT and scheme == REFERENCE_SCHEME:
        return dop853_reference(scene, times)
    return reference


def final_orientation_errors(scene, scheme, dts, interval, options=None):
    """Orientation error at the end of the run for each dt, against the scene's reference
    (`independent_reference`)."""
    errors = []
    reference = None
    for dt in dts:
        run = simulate([scene], scheme, dt, interval, options)
        if reference is None:
            reference = independent_reference(scene, run.time, scheme).quaternion
        errors.append(orientation_error(run.quaternion[0, -1], reference[-1]))
    return np.array(errors)


def write_study(folder, name="study", sweep=None, run=None, scene=None, output=None):
    """Write a study YAML into ``folder`` (the Abaqus top, 0.5 s, by default); returns its path."""
    study = {
        "name": name,
        "scene": scene or {**abaqus_mapping(), "duration": 0.5},
        "output": output or {"interval": 0.01},
        "run": run or {"scheme": "rk4", "dt": 0.01},
    }
    if sweep is not None:
        study["sweep"] = sweep
    path = pathlib.Path(folder) / f"{name}.yaml"
    path.write_text(yaml.safe_dump(study, sort_keys=False))
    return path


def sweep_until_a_batch_is_kept(config, out, kept="*.npz.sha256", options=(), wait=120):
    """``rbstudy sweep config --out out --quiet options`` started in a process of its own,
    returned once its study's first batch is kept (a file of ``kept`` in ``parts/``, its part's
    digest by default) or it has ended: the process, and the study's parts folder. For the
    tests that kill a sweep and resume it."""
    command = [sys.executable, "-m", "rbstudy", "sweep", str(config), "--out", str(out), "--quiet"]
    process = subprocess.Popen([*command, *options], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    parts = pathlib.Path(out) / pathlib.Path(config).stem / "parts"
    deadline = time.monotonic() + wait
    while not (parts.exists() and list(parts.glob(kept))) and process.poll() is None:
        assert time.monotonic() < deadline, f"no batch kept in {wait} s"
        time.sleep(0.01)
    return process, parts


# The variable that times the run: it differs between two runs of the same numbers (the cost of
# a step, `step_seconds`, is calibrated once on a machine: the same in every run there).
TIMINGS = ("run_time",)


def same_numbers(path_a, path_b):
    """Assert that the archives at ``path_a`` and ``path_b`` (netCDF or zarr) hold the same
    dataset, bit for bit, but for the run's timings and the global attributes (when and where
    each was run)."""
    import xarray as xr

    from rbstudy.archive.load import open_results

    a, b = open_results(path_a), open_results(path_b)
    xr.testing.assert_identical(a.drop_vars(TIMINGS).drop_attrs(), b.drop_vars(TIMINGS).drop_attrs())
