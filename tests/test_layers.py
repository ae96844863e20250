"""The import contract of docs/architecture.md, per folder: imports point downwards only, each
layer uses only the outside packages its job needs, and the analysis layer never loads numba.

    cli.py -> analysis/ -> pipeline/ -> physics/ -> engines/ -> schemes/ -> numerics/

`errors.py` and `reader.py` at the top of the package hold the user-facing errors and the one
input reader; every layer from the schemes up may use them, and they import nothing of
rbstudy but each other, and of the outside numpy only (a swept column is an array).
"""

import ast
import pathlib
import subprocess
import sys

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "rbstudy"

# Layers from the bottom up: a module may import its own layer and the layers below it.
LAYERS = ("numerics", "schemes", "engines", "physics", "pipeline", "analysis", "cli")
SHARED = ("errors", "reader")  # rbstudy/<name>.py, below every layer but numerics
RANK = {layer: rank for rank, layer in enumerate(LAYERS)}

# The outside packages (beyond the standard library) each layer may import.
OUTSIDE = {
    "numerics": {"numpy", "numba"},
    "schemes": {"numpy", "numba"},
    "engines": {"numpy", "mujoco", "pybullet", "exudyn", "pydrake"},  # each adapter its engine's own bindings
    "physics": {"numpy", "scipy"},
    "pipeline": {"numpy", "scipy", "xarray", "netCDF4", "dask", "distributed", "dask_jobqueue",
                 "yaml", "filelock", "rich"},
    "analysis": {"numpy", "xarray", "matplotlib", "tabulate", "jinja2", "markupsafe"},
    "cli": set(),
    "shared": {"numpy"},  # the reader checks a swept column of values at once
}
# The one scheme that wraps scipy's integrator.
SCIPY_SCHEME = "schemes/dop853.py"

# Modules the archive readers rely on: none of them may load numba (or the schemes), so that
# figures, tables and reports start in a moment and need no compiler.
NUMBA_FREE = ("rbstudy.analysis.plots", "rbstudy.analysis.summary", "rbstudy.analysis.report",
              "rbstudy.analysis.conformance", "rbstudy.analysis.findings",
              "rbstudy.pipeline.archive", "rbstudy.pipeline.store", "rbstudy.pipeline.variables",
              "rbstudy.pipeline.outputs",
              "rbstudy.pipeline.batches", "rbstudy.physics.analytic", "rbstudy.reader")


def layer_of(parts):
    """The layer of a module given by its path parts inside the package."""
    if parts[0] in LAYERS:
        return parts[0]
    if parts == ("cli",) or parts == ("__main__",):
        return "cli"
    if parts == ("extending",):  # the plug-ins' one import: the schemes' layer, re-exported
        return "schemes"
    if parts[0] in SHARED or parts == ("__init__",):
        return "shared"
    raise AssertionError(f"rbstudy/{'/'.join(parts)}.py belongs to no layer: move it into one")


def imports(path):
    """The absolute module names ``path`` imports; a relative import is named ``.relative``
    (refused: the contract is checked on absolute names)."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
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


def test_every_module_sits_in_a_layer_and_imports_downwards_only():
    violations = {"/".join(parts): found for path, parts in modules()
                  if (found := violations_of(path, parts))}
    assert not violations, violations


def test_the_contract_names_what_exists():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders == set(LAYERS) - {"cli"}
    assert all((PACKAGE / f"{name}.py").is_file() for name in SHARED + ("cli",))
    assert (PACKAGE / SCIPY_SCHEME).is_file()


def test_an_upward_import_is_caught(tmp_path):
    """The check itself can fail: a physics module importing the pipeline is reported."""
    bad = tmp_path / "bad.py"
    bad.write_text("from rbstudy.pipeline.store import open_results\nimport matplotlib\n"
                   "from .metrics import node_error\n")
    found = violations_of(bad, ("physics", "bad"))
    assert len(found) == 3 and "physics -> pipeline" in found[0] and "matplotlib" in found[1]
    assert "relative import" in found[2]


def test_the_archive_readers_never_load_numba():
    script = ("import sys\n" + "".join(f"import {name}\n" for name in NUMBA_FREE)
              + "loaded = [m for m in ('numba', 'rbstudy.schemes', 'rbstudy.numerics.driver') "
                "if m in sys.modules]\nassert not loaded, loaded\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr

