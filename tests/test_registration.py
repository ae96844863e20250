"""What the registry checks and reads when a scheme registers: the layout of its options in
the option row, and rbstudy's own engine adapters, registered as entry points."""

import dataclasses
import importlib.metadata

import pytest

from rbstudy.numerics.state import N_OPTION
from rbstudy.schemes import BUILTIN, Option
from rbstudy.schemes import _plugins as plugins


def _option(name, slot, width=1):
    return Option(
        name=name,
        default=0.5,
        description="a number",
        slot=slot,
        parse=lambda value: (float(value),) * width,
        width=width,
    )


def _register(*options):
    return dataclasses.replace(BUILTIN["hht"], name="twin", options=options)


def test_two_options_on_one_slot_are_refused_at_registration():
    """hht reads alpha at slot 0: an option sharing it would read alpha's value as its own."""
    with pytest.raises(ValueError) as caught:
        _register(_option("alpha", 0), _option("axis_order", 0, width=3))
    assert str(caught.value) == (
        "scheme 'twin': options 'alpha' and 'axis_order' both claim "
        "slot 0 of the option row; move one to a free slot"
    )
    with pytest.raises(ValueError, match="'axis_order' and 'composition' both claim slot 2"):
        _register(_option("axis_order", 0, width=3), _option("composition", 2))
    assert _register(_option("axis_order", 0, width=3), _option("composition", 3)).options


def test_an_option_outside_the_row_or_wider_than_declared_is_refused():
    with pytest.raises(ValueError) as caught:
        _register(_option("composition", N_OPTION))
    assert str(caught.value) == (
        f"scheme 'twin': option 'composition' takes slots {N_OPTION}-"
        f"{N_OPTION} of a row of {N_OPTION}; give it a slot from 0 to "
        f"{N_OPTION - 1}"
    )
    packs_two = dataclasses.replace(_option("axis_order", 0), parse=lambda value: (1.0, 2.0))
    with pytest.raises(ValueError, match="packs 2 values into a width of 1; declare width=2"):
        _register(packs_two)


def test_rbstudy_s_engine_schemes_are_its_own_entry_points():
    """Read from the source tree's pyproject.toml, which the test layer checks too, in the
    order of their names, as an installed rbstudy's metadata lists them."""
    assert plugins.ENGINES["mujoco_euler"] == "rbstudy.engines.mujoco:EULER"
    assert len(plugins.ENGINES) == 13 and list(plugins.ENGINES) == sorted(plugins.ENGINES)
    assert all(value.startswith("rbstudy.engines.") for value in plugins.ENGINES.values())


def test_an_installed_rbstudy_reads_its_engines_from_its_metadata(tmp_path, monkeypatch):
    """A wheel has no pyproject.toml beside its package: the installed metadata names them."""
    entries = importlib.metadata.EntryPoints(
        [
            importlib.metadata.EntryPoint("mujoco_rk4", "rbstudy.engines.mujoco:RK4", plugins.GROUP),
            importlib.metadata.EntryPoint("rbstudy", "rbstudy.cli:command", "console_scripts"),
            importlib.metadata.EntryPoint("drake_rk2", "rbstudy.engines.drake:RK2", plugins.GROUP),
        ]
    )
    installed = {"drake_rk2": "rbstudy.engines.drake:RK2", "mujoco_rk4": "rbstudy.engines.mujoco:RK4"}

    class Installed:
        entry_points = entries

    monkeypatch.setattr(plugins, "_PYPROJECT", tmp_path / "pyproject.toml")
    monkeypatch.setattr(
        importlib.metadata, "distribution", lambda name: Installed if name == "rbstudy" else None
    )
    assert list(plugins._own_entries().items()) == list(installed.items())
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "another"\n')  # not ours
    assert plugins._own_entries() == installed
