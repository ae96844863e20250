"""The catalogue of load kinds: every kind of load rbstudy knows, declared once.

Each `LoadKind` says what a load is (its key under ``scene.loads``, its frame, units and
width) and what it does (whether it turns the body, moves the centre of mass, only takes
energy out), where it may be given (at nodes, tabulated in time), and where it sits in a
parameter row. The scene reader, the row packer, the closed-form classifier, the references,
the engines and the kernels' row layout read it; `rbstudy.numerics.state` takes its offsets
from here, and numba freezes the module-level integers below into the kernels. Numba-free
and numpy-free, so that every layer may read it.

A parameter row holds the mass (1) and the principal inertias (3) first, then one slot of
``width`` values per kind, from `FIRST_SLOT`: the kinds that may be tabulated in time first,
so that a knot's record of tabulated loads is one slice of the row's layout
(`rbstudy.numerics.state.LOAD_RECORD`), then the kinds that are constant only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the module imports no numpy: its arrays come from the caller
    import numpy as np

__all__ = [
    "LoadKind",
    "LOAD_KINDS",
    "KIND",
    "FIRST_SLOT",
    "END_SLOT",
    "RECORD_WIDTH",
    "TURNING_SLOTS",
    "TURNING_RECORD_SLOTS",
    "BLOCKLESS_SLOTS",
    "FRAMES",
    "needs_time",
]

# What a kind's vector is given in: ``space`` axes, ``body`` axes (turned into the principal
# frame when the inertia is a full tensor), one value per ``principal`` axis (a coefficient,
# not a vector: it is not turned), and ``lever`` for the space forces at body-fixed points
# (derived from the loads at nodes, never given).
FRAMES = ("space", "body", "principal", "lever")

# The parameter row's mass (1) and principal inertias (3) come first (`rbstudy.numerics.state`).
FIRST_SLOT = 4


@dataclass(frozen=True)
class LoadKind:
    """A kind of load.

    name : its key under ``scene.loads`` and its `rbstudy.physics.scenes.Loads` field.
    frame : one of `FRAMES`. units : of its values, as docs/config.md writes them.
    width : values in the row.
    turns_body : it exerts a moment (a body on which none acts is moment-free).
    moves_centre : it pushes the centre of mass.
    dissipates : it only ever takes energy out (it bounds no moment that could speed the body
        up: the references' step planning leaves it out).
    given : a key of ``scene.loads`` (False: derived from other loads, the lever).
    at_nodes : it may be given at a node, and is aggregated to the centre of mass.
    tabulated : it may be tabulated in time (then part of a knot's record).
    timed_kernels : only the kernels compiled with the time carry it (`rbstudy.numerics.clock`):
        a check for a rare load in every evaluation of the moment costs the free body as a
        check for tabulated loads did, so the lean kernels leave it out (`needs_time`).
    meaning : one line for the docs and error messages.
    in_blocks : the block path (`rbstudy.numerics.block.loads_at`) carries it as a constant; a
        body with a kind it does not carry runs the single-body loop (`BLOCKLESS_SLOTS`). Never
        true of a kind of the timed kernels alone: the blocks run only without the time.
    offset : where its values start in a parameter row (set by the layout below).
    """

    name: str
    frame: str
    units: str
    width: int
    turns_body: bool
    moves_centre: bool
    meaning: str
    in_blocks: bool
    dissipates: bool = False
    given: bool = True
    at_nodes: bool = False
    tabulated: bool = True
    timed_kernels: bool = False
    offset: int = -1


def _laid_out(kinds):
    """``kinds`` with their offsets: the tabulated kinds from `FIRST_SLOT`, in the order
    given, then the constant-only kinds."""
    placed, at = [], FIRST_SLOT
    for kind in sorted(kinds, key=lambda kind: not kind.tabulated):  # stable
        if kind.frame not in FRAMES:
            raise ValueError(f"load kind {kind.name!r}: frame {kind.frame!r} is none of {FRAMES}")
        if kind.in_blocks and kind.timed_kernels:
            raise ValueError(f"load kind {kind.name!r}: the blocks run without the time, so never carry it")
        placed.append(replace(kind, offset=at))
        at += kind.width
    return tuple(placed)


LOAD_KINDS = _laid_out(
    (
        LoadKind(
            "force_space",
            "space",
            "N",
            3,
            turns_body=False,
            moves_centre=True,
            at_nodes=True,
            in_blocks=True,
            meaning="force at the centre of mass, fixed in space",
        ),
        LoadKind(
            "force_body",
            "body",
            "N",
            3,
            turns_body=False,
            moves_centre=True,
            at_nodes=True,
            in_blocks=False,
            meaning="force at the centre of mass, turning with the body",
        ),
        LoadKind(
            "moment_space",
            "space",
            "N m",
            3,
            turns_body=True,
            moves_centre=False,
            at_nodes=True,
            in_blocks=True,
            meaning="moment fixed in space",
        ),
        LoadKind(
            "moment_body",
            "body",
            "N m",
            3,
            turns_body=True,
            moves_centre=False,
            at_nodes=True,
            in_blocks=True,
            meaning="moment turning with the body",
        ),
        LoadKind(
            "gravity",
            "space",
            "m/s^2",
            3,
            turns_body=False,
            moves_centre=True,
            in_blocks=True,
            meaning="acceleration of gravity (the weight acts at the centre of mass)",
        ),
        LoadKind(
            "lever",
            "lever",
            "N m",
            9,
            turns_body=True,
            moves_centre=False,
            given=False,
            in_blocks=False,
            meaning="space forces at body-fixed points off the centre of mass, as the rows "
            "k_b = sum_i d_i[b] F_i whose moment turns with the body",
        ),
        LoadKind(
            "damping_moment",
            "principal",
            "N m s",
            3,
            turns_body=True,
            moves_centre=False,
            dissipates=True,
            tabulated=False,
            timed_kernels=True,
            in_blocks=False,
            meaning="linear damping moment M = -C w in body axes, C per principal axis",
        ),
    )
)
KIND = {kind.name: kind for kind in LOAD_KINDS}

# Past the last slot: the row's KNOTS (`rbstudy.numerics.state`).
END_SLOT = LOAD_KINDS[-1].offset + LOAD_KINDS[-1].width
# Values of one knot's record of tabulated loads: the tabulated kinds' slots, from FIRST_SLOT.
RECORD_WIDTH = sum(kind.width for kind in LOAD_KINDS if kind.tabulated)
# The kernels' moment-free check (`rbstudy.numerics.dynamics.is_moment_free`): the slots
# (start, width) of the kinds that turn the body, in the row and in a knot's record (from
# its start).
TURNING_SLOTS = tuple((kind.offset, kind.width) for kind in LOAD_KINDS if kind.turns_body)
TURNING_RECORD_SLOTS = tuple(
    (kind.offset - FIRST_SLOT, kind.width) for kind in LOAD_KINDS if kind.turns_body and kind.tabulated
)

# The slots (start, width) of the kinds the block path does not carry (`LoadKind.in_blocks`):
# a body with any of them non-zero runs the single-body loop (`rbstudy.numerics.block_run.plain_loads`).
BLOCKLESS_SLOTS = tuple((kind.offset, kind.width) for kind in LOAD_KINDS if not kind.in_blocks)


def needs_time(params: np.ndarray) -> np.ndarray:
    """(B,) True for the parameter rows ``params`` (B, W) that need the kernels compiled with
    the time (`rbstudy.numerics.clock`): loads tabulated in time (a count of knots, KNOTS,
    right after the last slot), or a kind of load only those kernels carry
    (`LoadKind.timed_kernels`).

    Parameters
    ----------
    params : ndarray, shape (B, W)
        Parameter rows, W >= N_PARAM (`rbstudy.numerics.state`).

    Returns
    -------
    ndarray of bool, shape (B,)
    """
    needed = params[:, END_SLOT] != 0.0
    for kind in LOAD_KINDS:
        if kind.timed_kernels:
            needed = needed | (params[:, kind.offset : kind.offset + kind.width] != 0.0).any(axis=1)
    return needed
