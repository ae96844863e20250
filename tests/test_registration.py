"""What the registry checks and reads when a scheme registers: the layout of its options in
the option row, and rbstudy's own engine adapters, registered as entry points."""

import dataclasses
import importlib.metadata

import pytest

from rbstudy.numerics.state import N_OPTION
from rbstudy.schemes import BUILTIN, Option, option_slots
from rbstudy.schemes import _plugins as plugins


def _option(name, slot=None, width=1):
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


def test_the_registry_lays_out_each_scheme_s_options_in_the_order_it_declares_them():
    """Each option at the first free run of its width; composition and compensated, shared
    by several schemes, sit where each scheme's layout puts them, and its row holds each
    value where its kernels read it (a composition at another slot would run as order 2)."""
    assert dict(option_slots([_option("a", width=3), _option("b"), _option("c")])) == {"a": 0, "b": 3, "c": 4}
    assert dict(BUILTIN["splitting"].slots) == {"axis_order": 0, "composition": 3, "compensated": 4}
    assert dict(BUILTIN["midpoint"].slots) == {"composition": 0, "compensated": 1}
    assert dict(BUILTIN["hht"].slots) == {"alpha": 0, "compensated": 1}
    row = BUILTIN["no_squish"].option_row({"axis_order": "312", "composition": 6, "compensated": 1})
    assert row.tolist() == [2.0, 0.0, 1.0, 6.0, 1.0]
    # a pinned slot (a plug-in written before the registry allocated them) is kept, and the
    # others fill around it
    assert dict(option_slots([_option("a"), _option("b", slot=0)])) == {"b": 0, "a": 1}


def test_two_options_on_one_slot_are_refused_at_registration():
    """An option pinned where another sits would read the other's value as its own."""
    with pytest.raises(ValueError) as caught:
        _register(_option("alpha", 0), _option("axis_order", 0, width=3))
    assert str(caught.value) == (
        "scheme 'twin': options 'alpha' and 'axis_order' both claim slot 0 of the option row; "
        "leave out the slot and the registry lays out the row"
    )
    with pytest.raises(ValueError, match="'axis_order' and 'composition' both claim slot 2"):
        _register(_option("axis_order", 0, width=3), _option("composition", 2))
    assert _register(_option("axis_order", 0, width=3), _option("composition", 3)).options


def test_an_option_outside_the_row_or_wider_than_declared_is_refused():
    with pytest.raises(ValueError) as caught:
        _register(_option("composition", N_OPTION))
    assert str(caught.value) == (
        f"scheme 'twin': option 'composition' takes slots {N_OPTION}-{N_OPTION} of a row of "
        f"{N_OPTION}; leave out the slot and the registry lays out the row"
    )
    packs_two = dataclasses.replace(_option("axis_order"), parse=lambda value: (1.0, 2.0))
    with pytest.raises(ValueError, match="packs 2 values into a width of 1; declare width=2"):
        _register(packs_two)
    with pytest.raises(ValueError, match="no 3 free slots left for option 'c' in a row of 5"):
        _register(_option("a", width=2), _option("b"), _option("c", width=3))


def test_block_scratch_rows_are_laid_out_in_order_and_bounded_by_the_block():
    """A block step's scratch rows (`scratch_rows`): each field at the next free row from
    `TEMP`, as hht's block step reads them; fields past the block's `N_TEMP` rows (which would
    overwrite its carried rows) or of no rows are refused in one line."""
    from rbstudy.numerics.block import N_TEMP, TEMP, WORK
    from rbstudy.schemes import hht
    from rbstudy.schemes._registry import scratch_rows

    assert scratch_rows("twin", a=3, b=1, c=4) == (TEMP, TEMP + 3, TEMP + 4)
    assert (hht._R_OLD, hht._SCALE, hht._W_NEW) == (TEMP, TEMP + 3, TEMP + 21)
    assert scratch_rows("twin", whole=N_TEMP) == (TEMP,) and TEMP + N_TEMP == WORK
    with pytest.raises(ValueError) as caught:
        scratch_rows("twin", stages=N_TEMP - 2, exp=4)
    assert str(caught.value) == (
        f"scheme 'twin': block scratch stages ({N_TEMP - 2}), exp (4) takes {N_TEMP + 2} rows of the "
        f"{N_TEMP} a block has; reuse rows in a second layout, or raise rbstudy.numerics.block.N_TEMP"
    )
    with pytest.raises(ValueError, match="block scratch 'exp' takes 0 rows; give 1 or more"):
        scratch_rows("twin", exp=0)


def test_rbstudy_s_engine_schemes_are_its_own_entry_points():
    """Read from the source tree's pyproject.toml, which the test layer checks too, in the
    order of their names, as an installed rbstudy's metadata lists them."""
    assert plugins.ENGINES["mujoco_euler"] == "rbstudy.engines.mujoco:EULER"
    assert len(plugins.ENGINES) == 14 and list(plugins.ENGINES) == sorted(plugins.ENGINES)
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
