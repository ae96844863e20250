"""Sizes a reader can hold in mind: no module of rbstudy over 600 lines and no function over 80,
except where the code says why.

A longer module says so in a comment among its first lines, a longer function in the comment
right above its ``def`` (above its decorators, if it has any), both in the form

    # longer than the limit: <the reason, in words>

A function's lines run from its ``def`` to its last line, its docstring included.
"""

import ast

from helpers import in_every_module, parsed

MODULE_LINES = 600
FUNCTION_LINES = 80
MARK = "# longer than the limit:"
# A reason is a sentence, not a word: the mark followed by at least this many words.
REASON_WORDS = 4
# A module's mark sits among its first lines (after its docstring would be too late to read).
MODULE_HEAD_LINES = 5


def _says_why(line):
    if MARK not in line:
        return False
    return len(line.split(MARK, 1)[1].split()) >= REASON_WORDS


def _comments_above(lines, first):
    """The comment lines right above line ``first`` (1-based), the nearest first."""
    above = []
    for line in reversed(lines[: first - 1]):
        if not line.strip().startswith("#"):
            break
        above.append(line)
    return above


def oversized(path, label=None):
    """The module's and its functions' excesses without a reason: a list of strings, each
    naming the file by ``label`` (its name if not given)."""
    label = label or path.name
    text = path.read_text()
    lines = text.splitlines()
    found = []
    if len(lines) > MODULE_LINES and not any(_says_why(line) for line in lines[:MODULE_HEAD_LINES]):
        found.append(f"{label}: {len(lines)} lines")
    for node in ast.walk(parsed(text)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        length = node.end_lineno - node.lineno + 1
        first = min([node.lineno] + [decorator.lineno for decorator in node.decorator_list])
        if length > FUNCTION_LINES and not any(_says_why(line) for line in _comments_above(lines, first)):
            found.append(f"{label}:{node.lineno} {node.name}: {length} lines")
    return found


def test_no_module_or_function_is_longer_than_the_limit_without_saying_why():
    found = in_every_module(oversized)
    assert not found, "past the size limits, with no reason given:\n" + "\n".join(found)


def test_an_oversized_function_or_module_is_caught(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(FUNCTION_LINES))
    long_function = tmp_path / "long_function.py"
    long_function.write_text(f"def f():\n{body}\n")
    assert oversized(long_function) == [f"long_function.py:1 f: {FUNCTION_LINES + 1} lines"]
    long_function.write_text(f"# longer than the limit: one table, read row by row\ndef f():\n{body}\n")
    assert oversized(long_function) == []
    long_function.write_text(
        f"# longer than the limit: one table of rows, read\n# row by row\ndef f():\n{body}\n"
    )
    assert oversized(long_function) == []
    long_function.write_text(f"# longer than the limit: one table, read row by row\n\ndef f():\n{body}\n")
    assert len(oversized(long_function)) == 1, "a comment apart from the function is not its reason"
    long_function.write_text(f"# longer than the limit: because\ndef f():\n{body}\n")
    assert len(oversized(long_function)) == 1, "a reason of one word is not a reason"

    long_module = tmp_path / "long_module.py"
    long_module.write_text("\n".join(f"x{i} = {i}" for i in range(MODULE_LINES + 1)) + "\n")
    assert oversized(long_module) == [f"long_module.py: {MODULE_LINES + 1} lines"]
    long_module.write_text(f"{MARK} one generated table of constants\n" + long_module.read_text())
    assert oversized(long_module) == []
