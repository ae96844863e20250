"""A hostile-input corpus built from every shipped config: an unknown key beside every
mapping, and in place of every scalar a value of the wrong kind (a nested list) and a number
beyond any float (10^400). Each mutation must fail in one line naming the file, with exit 1
and nothing written: never a traceback, never a silently ignored value."""

import contextlib
import copy
import io

import pytest
import yaml
from helpers import CONFIGS, HOSTILE, HOSTILE_SHOWN, TERMINAL_CONTROLS, copy_node_tables, write_study

from rbstudy.cli import main

# More than this many mutations come from the eight shipped configs (531 when written).
MIN_MUTATIONS = 100


def _places(node, path=()):
    """(kind, key path) of every mapping and every scalar of a loaded YAML document."""
    if isinstance(node, dict):
        yield "mapping", path
        for key, value in node.items():
            yield from _places(value, path + (key,))
    elif isinstance(node, list):
        for index, value in enumerate(node):
            yield from _places(value, path + (index,))
    elif path:
        yield "scalar", path
        yield "huge", path


def _mutated(study, kind, path):
    study = copy.deepcopy(study)
    node = study
    for part in path if kind == "mapping" else path[:-1]:
        node = node[part]
    if kind == "mapping":
        node["bogus_key"] = 1
    else:
        node[path[-1]] = [[]] if kind == "scalar" else 10**400
    return study


def mutations():
    for config in sorted(CONFIGS.glob("*.yaml")):
        study = yaml.safe_load(config.read_text())
        for kind, path in _places(study):
            yield config.stem, kind, path, _mutated(study, kind, path)


def _run(argv):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    return code, err.getvalue().strip()


@pytest.mark.slow
def test_every_mutation_of_the_shipped_configs_fails_in_one_line(tmp_path):
    failures, count = [], 0
    copy_node_tables(tmp_path)
    for stem, kind, path, study in mutations():
        count += 1
        name = f"{stem}_{kind}_{count}.yaml"
        config = tmp_path / name
        config.write_text(yaml.safe_dump(study, sort_keys=False))
        out = tmp_path / f"out_{count}"
        for verb in (["validate", str(config)], ["sweep", str(config), "--out", str(out)]):
            code, error = _run(verb)
            if code != 1 or "\n" in error or f"{config}: " not in error or out.exists():
                failures.append(f"{verb[0]} {stem} {kind} {path}: exit {code}: {error[-300:]}")
    assert count >= MIN_MUTATIONS
    assert not failures, "\n".join(failures[:20])


def test_control_characters_of_a_config_are_shown_not_obeyed(tmp_path, capsys):
    """A key of a config that would set the terminal's title and clear its screen is
    named in the error line as escapes."""
    config = write_study(tmp_path, name="top")
    study = yaml.safe_load(config.read_text())
    study["scene"]["body"][HOSTILE] = 1
    config.write_text(yaml.safe_dump(study, sort_keys=False))
    assert main(["validate", str(config)]) == 1
    error = capsys.readouterr().err
    assert f"rbstudy: error: {config}: scene.body.{HOSTILE_SHOWN}: unknown key" in error
    assert not TERMINAL_CONTROLS.search(error), repr(error)
