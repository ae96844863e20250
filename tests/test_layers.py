"""The layer contract of design.md: imports point downwards only.

numerics (numpy, numba; scipy only in the dop853 reference) <- physics <- pipeline <- cli.
"""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "rbstudy"

LAYERS = {
    "numerics": {"_jit", "state", "rotation", "dynamics", "driver", "schemes", "errors"},
    "physics": {"scenes", "assembly", "analytic", "metrics", "variables", "simulate", "outputs",
                "quaternions"},
    "pipeline": {"config", "sweep", "execute", "store", "summary", "plots", "report", "bench"},
    "cli": {"cli", "__main__"},
}
RANK = {layer: i for i, layer in enumerate(LAYERS)}
FORBIDDEN_IN_NUMERICS = {"xarray", "dask", "distributed", "yaml", "matplotlib", "netCDF4"}


def layer_of(module):
    for layer, names in LAYERS.items():
        if module in names:
            return layer
    raise AssertionError(f"rbstudy.{module} belongs to no layer: add it to LAYERS")


def imports(path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module


def test_imports_point_downwards():
    violations = []
    for path in PACKAGE.rglob("*.py"):
        relative = path.relative_to(PACKAGE).with_suffix("").parts
        if relative == ("__init__",):
            continue
        own = layer_of(relative[0])
        for name in imports(path):
            parts = name.split(".")
            if parts[0] == "rbstudy" and len(parts) > 1:
                if RANK[layer_of(parts[1])] > RANK[own]:
                    violations.append(f"{path.name} ({own}) imports {name}")
            elif own == "numerics" and parts[0] in FORBIDDEN_IN_NUMERICS:
                violations.append(f"{path.name} (numerics) imports {name}")
            elif own == "numerics" and parts[0] == "scipy" and path.name != "dop853.py":
                violations.append(f"{path.name} (numerics) imports scipy")
    assert not violations, violations
