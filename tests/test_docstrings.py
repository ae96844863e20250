"""The numerical functions say what they take and give, shapes included (issue 32): every
public function and method of `rbstudy/numerics/`, `rbstudy/pipeline/outputs.py` and
`rbstudy/pipeline/batch_data.py` has a numpydoc ``Parameters`` section naming each of its
parameters and, where it returns a value, a ``Returns`` section; an array there gives its
shape with axis letters (``shape (B, T, 4)``). Read from the source (ast), so compiled
functions count as written."""

import ast
import pathlib
import re

import pytest
from helpers import parsed

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "rbstudy"
DOCUMENTED = sorted(PACKAGE.glob("numerics/*.py")) + [
    PACKAGE / "pipeline" / name for name in ("batch_data.py", "outputs.py")
]

# A numpydoc section: its title, then a line of dashes as long.
SECTION = re.compile(r"^\s*(\w+)\n\s*(-+)\n", re.MULTILINE)
# An entry of Parameters or Returns: ``name : type`` or ``a, b : type`` at the section's indent.
ENTRY = re.compile(r"^(\s*)([\w*]+(?:, [\w*]+)*) : (.*)$")


def public_functions(tree):
    """``(qualified name, node)`` of the module's public functions and of the public methods
    of its public classes (a property is documented as the value it is: no sections)."""
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and not node.name.startswith("_"):
            yield node.name, node
        if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            for method in node.body:
                if (
                    isinstance(method, ast.FunctionDef)
                    and not method.name.startswith("_")
                    and not any("property" in ast.unparse(d) for d in method.decorator_list)
                ):
                    yield f"{node.name}.{method.name}", method


def parameters(function):
    """The names a caller passes, ``self`` left out."""
    arguments = function.args
    names = [a.arg for a in arguments.posonlyargs + arguments.args + arguments.kwonlyargs]
    names += [f"*{a.arg}" for a in (arguments.vararg, arguments.kwarg) if a is not None]
    return [name for name in names if name != "self"]


def returns_value(function):
    """Whether ``function`` itself (not a function nested in it) returns something other
    than None."""
    pending = list(function.body)
    while pending:
        node = pending.pop()
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda | ast.ClassDef):
            continue
        if (
            isinstance(node, ast.Return)
            and node.value is not None
            and not (isinstance(node.value, ast.Constant) and node.value.value is None)
        ):
            return True
        pending.extend(ast.iter_child_nodes(node))
    return False


def sections(docstring):
    """Section title -> its text, for the numpydoc sections of ``docstring``."""
    heads = [m for m in SECTION.finditer(docstring) if len(m.group(1)) == len(m.group(2))]
    if not heads:
        return {}
    ends = [m.start() for m in heads[1:]] + [len(docstring)]
    return {m.group(1): docstring[m.end() : end] for m, end in zip(heads, ends, strict=True)}


def entries(text):
    """``(names, type)`` of each entry of a section's ``text``: the lines at its least indent
    that read ``name : type`` (a type alone, as Returns may give it, has no names)."""
    lines = [line for line in text.splitlines() if line.strip()]
    indent = min(len(line) - len(line.lstrip()) for line in lines)
    found = []
    for line in lines:
        if len(line) - len(line.lstrip()) != indent:
            continue
        match = ENTRY.match(line)
        found.append((match.group(2).split(", "), match.group(3)) if match else ([], line.strip()))
    return found


def problems(function):
    """What ``function``'s docstring lacks, as short phrases."""
    docstring = ast.get_docstring(function) or ""
    found = sections(docstring)
    lacking = []
    if parameters(function):
        listed = [name for names, _ in entries(found.get("Parameters", "x")) for name in names]
        lacking += [f"parameter {name}" for name in parameters(function) if name not in listed]
    if returns_value(function) and "Returns" not in found:
        lacking.append("a Returns section")
    for title in ("Parameters", "Returns"):
        for names, kind in entries(found[title]) if title in found else ():
            if "ndarray" in kind and "shape (" not in kind:
                lacking.append(f"the shape of {', '.join(names) or 'the returned array'}")
    return lacking


@pytest.mark.parametrize("path", DOCUMENTED, ids=lambda path: path.name)
def test_public_numerical_functions_document_parameters_returns_and_shapes(path):
    tree = parsed(path.read_text())
    missing = {name: lacking for name, function in public_functions(tree) if (lacking := problems(function))}
    assert not missing, f"{path.relative_to(PACKAGE.parent)}: numpydoc lacks {missing}"


def test_the_check_sees_a_missing_parameter_return_and_shape():
    """The check itself: a docstring that names one of two parameters, returns an array
    without its shape, or has no Returns section, is caught."""
    source = '''
def f(a, b):
    """Sum.

    Parameters
    ----------
    a : ndarray, shape (B, 3)
        One.

    Returns
    -------
    ndarray
        The sum.
    """
    return a + b


def g(a):
    """Nothing said."""
    return a
'''
    functions = dict(public_functions(parsed(source)))
    assert problems(functions["f"]) == ["parameter b", "the shape of the returned array"]
    assert problems(functions["g"]) == ["parameter a", "a Returns section"]
