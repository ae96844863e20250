"""The catalogue of load kinds: the row layout it draws, and the docs that list its keys."""

import pathlib

import numpy as np

from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics import state as S
from rbstudy.numerics.loads import FIRST_SLOT, LOAD_KINDS, needs_time
from rbstudy.physics.loads import Loads, turning

CONFIG_MD = pathlib.Path(__file__).parents[1] / "docs" / "config.md"


def test_the_slots_tile_the_row_after_the_inertias_tabulated_kinds_first():
    assert FIRST_SLOT == S.INERTIA + 3
    ends = [kind.offset + kind.width for kind in LOAD_KINDS]
    assert [kind.offset for kind in LOAD_KINDS] == [FIRST_SLOT] + ends[:-1]
    assert ends[-1] == S.KNOTS == S.N_PARAM - 1
    tabulated = [kind.tabulated for kind in LOAD_KINDS]
    assert tabulated == sorted(tabulated, reverse=True)  # a knot's record is one slice
    assert S.LOAD_RECORD == sum(kind.width for kind in LOAD_KINDS if kind.tabulated)


def test_every_kind_has_its_field_and_its_slot_in_the_row():
    """A value in each kind's field lands in that kind's slot and nowhere else."""
    for kind in LOAD_KINDS:
        values = tuple(float(k + 1) for k in range(kind.width))
        scene = scene_from_mapping({"body": {"inertia": [1.0, 2.0, 3.0]}})
        row = scene.with_changes(loads=Loads(**{kind.name: values})).param_row()
        assert row[kind.offset : kind.offset + kind.width].tolist() == list(values)
        assert np.count_nonzero(row[FIRST_SLOT:]) == kind.width, kind.name
        assert bool(turning(vars(Loads(**{kind.name: values})))) == kind.turns_body
        assert needs_time(row[None, :])[0] == kind.timed_kernels, kind.name


def test_loads_is_checked_against_the_catalogue(monkeypatch):
    """`Loads` is declared field by field; a kind the catalogue gains and `Loads` lacks (or
    one of another width) stops the import with what each holds."""
    import dataclasses

    import pytest

    from rbstudy.physics import loads

    loads._check_against_catalogue()  # as the import did
    wider = tuple(
        dataclasses.replace(kind, width=4) if kind.name == "gravity" else kind for kind in LOAD_KINDS
    )
    extra = (*LOAD_KINDS, dataclasses.replace(LOAD_KINDS[0], name="magnetic_moment"))
    for catalogue in (wider, extra):
        monkeypatch.setattr(loads, "LOAD_KINDS", catalogue)
        with pytest.raises(ImportError, match="the load catalogue wants"):
            loads._check_against_catalogue()


def test_config_md_names_every_key_with_its_units():
    text = CONFIG_MD.read_text()
    for kind in LOAD_KINDS:
        if not kind.given:
            continue
        row = next(
            line
            for line in text.splitlines()
            if line.startswith("| `loads.") and f"`loads.{kind.name}`" in line
        )
        assert row.split("|")[3].strip() == kind.units, (kind.name, row)
