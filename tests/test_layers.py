"""The import contract of docs/architecture.md, per folder: imports point downwards only, each
layer uses only the outside packages its job needs, and the analysis layer never loads numba.

    cli.py -> analysis/ -> pipeline/ -> archive/ -> inputs/ -> physics/ -> engines/ -> schemes/ -> numerics/

`inputs/` is the one layer that reads YAML or files (the reader, the YAML loader, the table
files, the scene readers): it returns physics objects, and physics never imports it.
`archive/` is the study folder on disk (its files, parts, archive, checksums, metadata table):
it never imports the sweep, so that a worker writing a part, or a reader, loads the archive
alone.
`errors.py` at the top of the package holds the user-facing errors; every layer from the
schemes up may use it, and it imports nothing of rbstudy, and of the outside nothing.

Every import counts, the ones named in strings too: ``importlib.import_module("...")`` and
``__import__("...")`` in a module, and the entry points of pyproject.toml that the scheme
registry loads (rbstudy's engine adapters), which must name modules of the engines layer.
"""

import ast
import functools
import pathlib
import subprocess
import sys

import pytest
import tomllib
from helpers import parsed

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "rbstudy"
PYPROJECT = PACKAGE.parent / "pyproject.toml"

# Layers from the bottom up: a module may import its own layer and the layers below it.
LAYERS = ("numerics", "schemes", "engines", "physics", "inputs", "archive", "pipeline", "analysis", "cli")
SHARED = ("errors",)  # rbstudy/<name>.py, below every layer but numerics
RANK = {layer: rank for rank, layer in enumerate(LAYERS)}

# The outside packages (beyond the standard library) each layer may import.
OUTSIDE = {
    "numerics": {"numpy", "numba"},
    "schemes": {"numpy", "numba"},
    "engines": {
        "numpy",
        "mujoco",
        "pybullet",
        "exudyn",
        "pydrake",
        "rapier3d",
    },  # each adapter its engine's own bindings
    "physics": {"numpy", "scipy"},
    "inputs": {"numpy", "scipy", "yaml"},
    "archive": {"numpy", "xarray", "netCDF4", "h5py", "filelock", "zarr"},
    "pipeline": {"numpy", "scipy", "xarray", "dask", "distributed", "dask_jobqueue", "yaml", "rich"},
    "analysis": {"numpy", "xarray", "matplotlib", "tabulate", "jinja2", "markupsafe"},
    "cli": set(),
    "shared": set(),
}
# The one scheme that wraps scipy's integrator.
SCIPY_SCHEME = "schemes/dop853.py"

# The entry-point group the scheme registry loads (rbstudy.schemes._plugins), and the layer
# its modules belong to: above the schemes, whose registry loads them, below the physics.
ENTRY_POINT_GROUP = "rbstudy.schemes"
PLUGIN_LAYER = "engines"
# Modules the archive readers rely on: every module of the analysis layer and these below it;
# and every module of the inputs layer, so that reading the input compiles nothing.
# None of them may load numba (or the schemes), so that figures, tables and reports start in
# a moment and need no compiler.
NUMBA_FREE = (
    *(
        f"rbstudy.{layer}.{path.stem}"
        for layer in ("analysis", "archive", "inputs")
        for path in sorted((PACKAGE / layer).glob("*.py"))
        if path.stem != "__init__"
    ),
    "rbstudy.pipeline.outputs",
    "rbstudy.pipeline.batch_data",
    "rbstudy.pipeline.batches",
    "rbstudy.physics.analytic",
)
# The calls that import the module their first argument names.
IMPORT_CALLS = ("import_module", "__import__")


def layer_of(parts):
    """The layer of a module given by its path parts inside the package."""
    if parts[0] in LAYERS:
        return parts[0]
    if parts == ("cli",) or parts == ("__main__",) or parts[0] == "commands":  # the verbs of cli.py
        return "cli"
    if parts == ("extending",):  # the plug-ins' one import: the schemes' layer, re-exported
        return "schemes"
    if parts[0] in SHARED or parts == ("__init__",):
        return "shared"
    raise AssertionError(f"rbstudy/{'/'.join(parts)}.py belongs to no layer: move it into one")


def _called(node):
    """The name of the function a call calls (``import_module`` for importlib.import_module)."""
    function = node.func
    return function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", None)


@functools.cache
def _tree(path):
    """The parsed source of ``path``, once a session: every check here walks the same files."""
    return parsed(path.read_text())


def imports(path):
    """The absolute module names ``path`` imports, by statement or by a string given to
    `IMPORT_CALLS`; a relative import is named ``.relative`` (refused: the contract is checked
    on absolute names)."""
    tree = _tree(path)
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and _called(node) in IMPORT_CALLS
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            yield node.args[0].value
        elif isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            yield ".relative"
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module
            if node.module == "rbstudy":  # from rbstudy import errors
                yield from (f"rbstudy.{alias.name}" for alias in node.names)


def modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        yield path, path.relative_to(PACKAGE).with_suffix("").parts


def violations_of(path, parts):
    own = layer_of(parts)
    found = []
    for name in imports(path):
        top = name.split(".")
        if name == ".relative":
            found.append("a relative import: write it absolute (rbstudy.<layer>.<module>)")
        elif top[0] == "rbstudy":
            if len(top) == 1:
                continue
            target = layer_of(tuple(top[1:]))
            if target == "shared":
                if own == "numerics":
                    found.append(f"{name}: the numerics layer needs no rbstudy module above it")
            elif own == "shared" or RANK[target] > RANK[own]:
                found.append(f"{name}: imports upwards ({own} -> {target})")
        elif top[0] not in sys.stdlib_module_names and top[0] not in OUTSIDE[own]:
            if not (top[0] == "scipy" and "/".join(parts) + ".py" == SCIPY_SCHEME):
                found.append(f"{name}: not a package the {own} layer may use")
    return found


def entry_point_violations(entry_points):
    """What is wrong with ``entry_points`` (name -> "module:attribute") of the group the
    registry loads: each of rbstudy's must name a module of `PLUGIN_LAYER`."""
    found = []
    for name, value in entry_points.items():
        module = value.partition(":")[0]
        if module.split(".")[0] == "rbstudy":
            layer = layer_of(tuple(module.split(".")[1:]))
            if layer != PLUGIN_LAYER:
                found.append(
                    f"entry point {name} = {value!r}: the scheme registry would load "
                    f"the {layer} layer; register schemes from the {PLUGIN_LAYER} layer"
                )
    return found


def module_name(parts):
    """The dotted name of the module at ``parts`` (a package by its ``__init__``)."""
    return ".".join(("rbstudy", *parts[:-1], *([] if parts[-1] == "__init__" else [parts[-1]])))


def edges(path, known):
    """The modules of ``known`` (dotted names) that ``path`` imports, anywhere in it (inside a
    function too): ``from rbstudy.numerics import state`` names ``rbstudy.numerics.state``."""
    found = set(imports(path))
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found & known


def circles(graph):
    """The import circles of ``graph`` (module -> the modules it imports): each a list of
    modules, each importing the next and the last the first (Tarjan's strongly connected
    components of more than one module, or of one importing itself)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(module):
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for target in sorted(graph.get(module, ())):
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in on_stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == module:
                    break
            if len(component) > 1 or module in graph.get(module, ()):
                found.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return found


@functools.lru_cache(maxsize=1)
def import_graph():
    found = {module_name(parts): path for path, parts in modules()}
    return {name: edges(path, found.keys() - {name}) for name, path in found.items()}


@pytest.mark.slow
def test_the_import_graph_has_no_circle():
    """No module imports, through any chain, one that imports it: an import made inside a
    function counts (it hides a circle, it does not break it). The floor of the numerics
    had one (driver -> entry -> block -> driver), and the scheme registry another."""
    assert circles(import_graph()) == []


@pytest.mark.slow
def test_an_import_circle_is_caught():
    """The check itself can fail: the numerics' old circle, rebuilt, is found, and an import
    that only points down is not."""
    graph = import_graph()
    assert "rbstudy.numerics.block" in graph["rbstudy.numerics.entry"]
    planted = {
        **graph,
        "rbstudy.numerics.block": graph["rbstudy.numerics.block"] | {"rbstudy.numerics.entry"},
    }
    assert circles(planted) == [["rbstudy.numerics.block", "rbstudy.numerics.entry"]]
    assert circles({"a": {"b"}, "b": set(), "c": {"c"}}) == [["c"]]


@pytest.mark.slow
def test_every_module_sits_in_a_layer_and_imports_downwards_only():
    violations = {
        "/".join(parts): found for path, parts in modules() if (found := violations_of(path, parts))
    }
    assert not violations, violations


def test_the_entry_points_the_registry_loads_are_engine_adapters():
    entry_points = tomllib.loads(PYPROJECT.read_text())["project"]["entry-points"]
    own = entry_points[ENTRY_POINT_GROUP]
    assert own, "rbstudy registers its engine adapters as entry points"
    assert not entry_point_violations(own)
    for value in own.values():  # each names a module that exists
        module = value.partition(":")[0]
        assert (PACKAGE.parent / (module.replace(".", "/") + ".py")).is_file(), value


def test_the_contract_names_what_exists():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders == set(LAYERS) - {"cli"} | {"commands"}
    assert all((PACKAGE / f"{name}.py").is_file() for name in SHARED + ("cli",))
    assert (PACKAGE / SCIPY_SCHEME).is_file()


def test_an_upward_import_is_caught(tmp_path):
    """The check itself can fail: a physics module importing the pipeline is reported."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from rbstudy.pipeline.execute import run_study\nimport matplotlib\nfrom .metrics import node_error\n"
    )
    found = violations_of(bad, ("physics", "bad"))
    assert len(found) == 3 and "physics -> pipeline" in found[0] and "matplotlib" in found[1]
    assert "relative import" in found[2]


def test_physics_reading_input_is_caught(tmp_path):
    """Physics holds the data model and never reads input: a physics module importing the
    inputs layer (the scene reader, the YAML loader) is reported, the inputs layer importing
    physics is not."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from rbstudy.inputs.scenes import scene_table\nimport yaml\n"
        "from rbstudy.physics.scenes import SceneTable\n"
    )
    found = violations_of(bad, ("physics", "bad"))
    assert len(found) == 2 and "physics -> inputs" in found[0] and "yaml" in found[1], found
    assert violations_of(bad, ("inputs", "bad")) == []


def test_an_upward_import_by_a_string_is_caught(tmp_path):
    """A module named in a string counts as imported: a scheme module loading an engine
    adapter or the physics by name, or the analysis layer loading numba, is reported; a name
    built at run time (the registry's own scheme modules) is not a module name to check."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import importlib\nfrom importlib import import_module\n"
        "importlib.import_module('rbstudy.engines.mujoco')\n"
        "import_module('rbstudy.physics.scenes')\n__import__('numba')\n"
        "importlib.import_module(f'{__name__}.euler')\n"
    )
    found = violations_of(bad, ("schemes", "bad"))
    assert len(found) == 2, found
    assert "schemes -> engines" in found[0] and "schemes -> physics" in found[1]
    assert violations_of(bad, ("analysis", "bad"))[-1] == "numba: not a package the analysis layer may use"


def test_an_entry_point_into_another_layer_is_caught():
    found = entry_point_violations(
        {
            "mujoco_euler": "rbstudy.engines.mujoco:EULER",
            "odd": "rbstudy.pipeline.bench:SCHEME",
            "other": "rbstudy_semi_implicit.compiled:SCHEME",
        }
    )
    assert len(found) == 1 and "odd" in found[0] and "the pipeline layer" in found[0]


def _loaded(names, unwanted):
    """The modules among ``sys.modules`` for which ``unwanted`` (a Python expression of ``m``,
    a module's name) holds, once ``names`` are imported in a fresh process."""
    script = "".join(f"import {name}\n" for name in ("sys", *names)) + (
        f"print([m for m in sorted(sys.modules) if {unwanted}])"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


@pytest.mark.slow
def test_the_archive_readers_never_load_numba():
    assert _loaded(NUMBA_FREE, "m in ('numba', 'rbstudy.schemes', 'rbstudy.numerics.driver')") == "[]"


def test_the_archive_loads_no_pipeline_module():
    """Every module of the archive package imported in a fresh process loads nothing of the
    sweep (so a worker writing its part, or a reader, needs the archive alone) and no numba."""
    names = [f"rbstudy.archive.{path.stem}" for path in sorted((PACKAGE / "archive").glob("*.py"))]
    assert _loaded(names, "m.startswith('rbstudy.pipeline') or m == 'numba'") == "[]"


def test_an_archive_module_importing_the_sweep_is_caught(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from rbstudy.pipeline.batches import Batch\nimport dask\n")
    found = violations_of(bad, ("archive", "bad"))
    assert len(found) == 2 and "archive -> pipeline" in found[0] and "dask" in found[1], found
