"""Groups of schemes on `rbstudy conformance --schemes` and `rbstudy bench`: one per engine
of the registry's `ENGINES`, ``engines`` and ``builtin``, expanded to the available schemes,
each once."""

import pytest

from rbstudy.cli import main
from rbstudy.errors import SchemeError
from rbstudy.schemes import BUILTIN, SCHEMES, Unavailable, expand_groups, get_scheme, scheme_groups
from rbstudy.schemes._plugins import ENGINES


def test_each_engine_of_the_registry_is_a_group_of_its_adapters():
    groups = scheme_groups()
    engines = {value.split(":")[0].rsplit(".", 1)[1] for value in ENGINES.values()}
    assert {"mujoco", "bullet", "exudyn", "drake"} <= engines
    for engine in engines:
        assert groups[engine] == [
            name for name, value in ENGINES.items() if value.startswith(f"rbstudy.engines.{engine}:")
        ]
    assert groups["engines"] == list(ENGINES)
    assert groups["builtin"] + groups["published"] == [
        name for name, scheme in BUILTIN.items() if not scheme.adaptive and scheme.group == "builtin"
    ] + [name for name, scheme in BUILTIN.items() if scheme.group == "published"]
    assert groups["published"] == ["buss", "jolt", "lgvi", "simo_wong"]
    assert "dop853" not in groups["builtin"] and "rk4" in groups["builtin"]


def test_groups_mix_with_names_and_each_scheme_is_taken_once():
    expanded = expand_groups(["rk4", "builtin", "euler"])
    assert expanded[0] == "rk4" and len(expanded) == len(set(expanded))
    assert set(expanded) == set(scheme_groups()["builtin"])
    assert expand_groups(["nope"]) == ["nope"]  # get_scheme refuses it, with the valid names


def _without_drake(monkeypatch):
    """The registry as on a machine without Drake: its schemes are listed unavailable."""
    find = SCHEMES.find

    def find_without_drake(name):
        if name.startswith("drake_"):
            return Unavailable(name, "needs the pydrake package", "pip install drake", "rbstudy")
        return find(name)

    monkeypatch.setattr(SCHEMES, "find", find_without_drake)


def test_a_group_whose_engine_is_absent_is_refused_with_the_install_command(monkeypatch):
    _without_drake(monkeypatch)
    with pytest.raises(
        SchemeError,
        match="--schemes: the group 'drake' has no scheme available "
        "here: needs the pydrake package; pip install drake",
    ):
        expand_groups(["rk4", "drake"])
    assert not any(name.startswith("drake_") for name in expand_groups(["engines"]))


def test_the_command_refuses_an_absent_engine_in_one_line(monkeypatch, tmp_path, capsys):
    _without_drake(monkeypatch)
    assert main(["conformance", "--schemes", "rk4,drake", "--out", str(tmp_path)]) == 1
    error = capsys.readouterr().err
    assert error == (
        "rbstudy: error: --schemes: the group 'drake' has no scheme available here: "
        "needs the pydrake package; pip install drake\n"
    )
    assert not list(tmp_path.iterdir())


def test_bench_takes_groups_as_conformance_does(capsys):
    """`bench --schemes builtin,rk4` times each of rbstudy's fixed-step schemes once (before:
    "unknown scheme 'builtin'")."""
    assert main(["bench", "--schemes", "builtin,rk4", "--body-steps", "200", "--quiet"]) == 0
    rows = [line.split()[0] for line in capsys.readouterr().out.splitlines()[4:]]
    assert rows == scheme_groups()["builtin"]


def test_bench_refuses_an_absent_engine_in_one_line(monkeypatch, capsys):
    _without_drake(monkeypatch)
    assert main(["bench", "drake", "--body-steps", "200", "--quiet"]) == 1
    assert capsys.readouterr().err == (
        "rbstudy: error: --schemes: the group 'drake' has no scheme available here: needs the "
        "pydrake package; pip install drake\n"
    )


def test_bench_passes_an_option_to_the_schemes_that_offer_it(monkeypatch, capsys):
    """`bench --option compensated=1` runs euler's compensated kernels (its batches' option
    rows set the flag at euler's slot) and dop853 as it is, and says which."""
    import rbstudy.pipeline.bench as bench

    seen = {}
    real = bench.run_batch

    def spy(scheme, state0, params, options, *rest, **keywords):
        seen.setdefault(scheme.name, set()).update(map(tuple, options.tolist()))
        return real(scheme, state0, params, options, *rest, **keywords)

    monkeypatch.setattr(bench, "run_batch", spy)
    given = ["bench", "euler", "dop853", "--option", "compensated=1", "--body-steps", "200"]
    assert main([*given, "--quiet"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out[4:6]] == ["euler*", "dop853"]
    assert out[6] == "* with compensated=1; the others have no such option"
    euler = get_scheme("euler")
    assert seen == {
        "euler": {tuple(euler.option_row({"compensated": 1}))},
        "dop853": {tuple(get_scheme("dop853").option_row())},
    }
    assert euler.option_row({"compensated": 1})[euler.slots["compensated"]] == 1.0
    assert main(["bench", "dop853", "--option", "compensated=1", "--quiet"]) == 1
    assert capsys.readouterr().err == (
        "rbstudy: error: --option: no scheme measured has an option 'compensated'; their options: none\n"
    )
