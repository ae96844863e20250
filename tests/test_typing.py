"""Every public function of rbstudy outside the compiled kernels says its types: each
parameter (but ``self`` and ``cls``) and its return are annotated, so that the type checker
CI runs (mypy, pinned in the test extra, configured in pyproject.toml) reads every call.

Public: a module-level function, or a method of a module-level class, whose name does not
start with an underscore (``__init__`` and the other dunders count as public: they are how
the object is built and used). The compiled kernels (``@jit``, ``@inline_jit`` and numba's
``@overload``) are left out: numba infers their types from the arrays it is given.
"""

import ast

from helpers import in_every_module, parsed

KERNEL_DECORATORS = {"jit", "inline_jit", "overload"}


def _decorator_name(node):
    target = node.func if isinstance(node, ast.Call) else node
    return target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")


def _public(name):
    return not name.startswith("_") or (name.startswith("__") and name.endswith("__"))


def _is_kernel(function):
    return any(_decorator_name(node) in KERNEL_DECORATORS for node in function.decorator_list)


def _unannotated(function):
    arguments = function.args
    every = arguments.posonlyargs + arguments.args + arguments.kwonlyargs
    every += [a for a in (arguments.vararg, arguments.kwarg) if a is not None]
    missing = [a.arg for a in every if a.annotation is None and a.arg not in ("self", "cls")]
    if function.returns is None and function.name != "__init__":
        missing.append("return")
    return missing


def untyped(path, label=None):
    """The public functions of one file whose types are not all said: a list of strings."""
    label = label or path.name
    found = []
    tree = parsed(path.read_text())
    functions = [(node, "") for node in tree.body if isinstance(node, ast.FunctionDef)]
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            functions += [(item, f"{node.name}.") for item in node.body if isinstance(item, ast.FunctionDef)]
    for function, owner in functions:
        if _public(function.name) and not _is_kernel(function):
            missing = _unannotated(function)
            if missing:
                found.append(f"{label}:{function.lineno} {owner}{function.name}: {', '.join(missing)}")
    return found


def test_every_public_function_outside_the_kernels_is_annotated():
    found = in_every_module(untyped)
    assert not found, f"{len(found)} public functions without their types:\n" + "\n".join(found)


def test_an_unannotated_public_function_is_caught(tmp_path):
    module = tmp_path / "module.py"
    module.write_text(
        "from numba import njit as jit\n"
        "def typed(x: int, *rest: float, scale: float = 1.0) -> float:\n    return x\n"
        "def half(x: int, y) -> int:\n    return x\n"
        "def no_return(x: int):\n    return x\n"
        "def _private(x):\n    return x\n"
        "@jit\ndef kernel(x):\n    return x\n"
        "class Body:\n"
        "    def __init__(self, mass: float):\n        self.mass = mass\n"
        "    def weight(self, g):\n        return self.mass * g\n"
    )
    assert untyped(module) == [
        "module.py:4 half: y",
        "module.py:6 no_return: return",
        "module.py:16 Body.weight: g, return",
    ]
