"""What the loads of scenes do, read from the catalogue of load kinds (`rbstudy.numerics.loads`).

`Loads` is one scene's loads, a field per kind of the catalogue; the predicates below ask
the same questions (does a load of these kinds act? does a moment? does a load vary in
time?) of one scene's fields (``vars(loads)``) or of a `rbstudy.physics.scenes.SceneTable`'s
columns alike: a bool, or (n,).
"""

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.numerics.loads import FIRST_SLOT, KIND, LOAD_KINDS

__all__ = [
    "Flags",
    "Loads",
    "TABLES",
    "GIVEN",
    "TURNING",
    "MOVING",
    "TABULATED",
    "BLOCKLESS",
    "acting",
    "constant_acting",
    "turning",
    "moving",
    "timed",
    "needs_time",
    "record_slice",
]

# The kinds a scene's ``loads`` block may name; those that turn the body, that move its
# centre, that may be tabulated in time.
GIVEN = tuple(kind.name for kind in LOAD_KINDS if kind.given)
TURNING = tuple(kind.name for kind in LOAD_KINDS if kind.turns_body)
MOVING = tuple(kind.name for kind in LOAD_KINDS if kind.moves_centre)
TABULATED = tuple(kind.name for kind in LOAD_KINDS if kind.tabulated)
# The kinds whose bodies the block path does not step (`rbstudy.numerics.loads.LoadKind.in_blocks`).
BLOCKLESS = tuple(kind.name for kind in LOAD_KINDS if not kind.in_blocks)
# The `Loads` fields of the loads tabulated in time.
TABLES = ("knots", "tabulated")

# Whether a load acts: one answer (a bool, or numpy's) for one scene, an array (n,) for a table.
Flags = bool | np.bool_ | np.ndarray


def record_slice(name: str) -> slice:
    """Where the kind ``name`` sits in a knot's record of tabulated loads."""
    start = KIND[name].offset - FIRST_SLOT
    return slice(start, start + KIND[name].width)


def _nonzero(*vectors):
    """Whether any of ``vectors`` (each (..., k), one k for all) has a non-zero entry: a bool,
    or (...,)."""
    return np.any(np.stack(np.broadcast_arrays(*vectors)) != 0.0, axis=(0, -1))


def _tabulated_acting(record, names):
    """Whether any of the kinds ``names`` has a non-zero entry at some knot of ``record``
    (..., K, LOAD_RECORD), the loads tabulated in time: a bool, or (...,)."""
    record = np.asarray(record, dtype=float)
    if record.ndim == 3 and len(record) > 1 and record.strides[0] == 0:  # one row, broadcast
        return np.broadcast_to(_tabulated_acting(record[:1], names), record.shape[:1])
    chosen = [record[..., record_slice(name)] for name in names if KIND[name].tabulated]
    if not chosen:
        return np.zeros(record.shape[:-2], dtype=bool)[()]
    return np.any(np.concatenate(chosen, axis=-1) != 0.0, axis=(-2, -1))


def constant_acting(loads: Mapping[str, Any], names: Iterable[str]) -> Flags:
    """Whether a constant load of the kinds ``names`` acts (``loads``: kind name -> values)."""
    found: Flags = False
    for name in names:
        found = found | _nonzero(loads[name])
    return found


def acting(loads: Mapping[str, Any], names: Iterable[str]) -> Flags:
    """Whether a load of the kinds ``names`` acts, constant or tabulated in time."""
    return constant_acting(loads, names) | _tabulated_acting(loads["tabulated"], names)


def turning(loads: Mapping[str, Any]) -> Flags:
    """Whether a moment acts (a kind that turns the body), constant or tabulated."""
    return acting(loads, TURNING)


def moving(velocity: Any, loads: Mapping[str, Any]) -> Flags:
    """Whether the centre of mass moves: an initial ``velocity``, or a force."""
    return _nonzero(velocity) | acting(loads, MOVING)


def timed(loads: Mapping[str, Any]) -> Flags:
    """Whether some load varies in time."""
    return _tabulated_acting(loads["tabulated"], TABULATED)


def needs_time(loads: Mapping[str, Any]) -> bool:
    """Whether some scene of ``loads`` (a `SceneTable`'s columns) needs the kernels compiled
    with the time (`rbstudy.numerics.loads.needs_time`, on parameter rows): a load table, or
    a kind of load only those kernels carry. One bool."""
    rare = [kind.name for kind in LOAD_KINDS if kind.timed_kernels]
    return bool(np.shape(loads["knots"])[-1] > 0 or np.any(constant_acting(loads, rare)))


@dataclasses.dataclass(frozen=True)
class Loads:
    """A scene's loads: a field per kind of the catalogue `rbstudy.numerics.loads`, in its
    order (its frame, units and width there; checked against it when this module is imported),
    in the principal frame; ``lever`` (9,) N m holds the space forces that act at body-fixed
    points off the centre of mass, as `rbstudy.numerics.state` lays out ``LEVER`` (their sum is
    in ``force_space``). These are constant; loads tabulated in time add to them: their
    ``knots`` (K,) s and, at each knot, a record ``tabulated`` (K, LOAD_RECORD) of the
    tabulated kinds in the parameter row's layout (`rbstudy.numerics.state.KNOTS`); arrays,
    views of the `SceneTable`'s (a long table is held once, not once per scene), left out of
    comparisons as `Scene.nodes` is."""

    force_space: tuple = (0.0,) * 3
    force_body: tuple = (0.0,) * 3
    moment_space: tuple = (0.0,) * 3
    moment_body: tuple = (0.0,) * 3
    gravity: tuple = (0.0,) * 3
    lever: tuple = (0.0,) * 9
    damping_moment: tuple = (0.0,) * 3
    knots: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0), compare=False)
    tabulated: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros((0, S.LOAD_RECORD)), compare=False
    )

    @property
    def moment_free(self) -> bool:
        """True when no load turns the body."""
        return not turning(vars(self))

    @property
    def timed(self) -> bool:
        """True when a load varies in time."""
        return bool(timed(vars(self)))


def _check_against_catalogue():
    """`Loads` has a field per kind of the catalogue, in its order and of its width, then the
    tables in time: a kind added to the catalogue must be added here."""
    fields = [(field.name, field.default) for field in dataclasses.fields(Loads)]
    wanted = [(kind.name, (0.0,) * kind.width) for kind in LOAD_KINDS]
    if fields[: len(wanted)] != wanted or [name for name, _ in fields[len(wanted) :]] != list(TABLES):
        raise ImportError(
            f"rbstudy.physics.loads.Loads has the fields {[name for name, _ in fields]}; the load "
            f"catalogue wants {[name for name, _ in wanted]} (each of its width), then {list(TABLES)}"
        )


_check_against_catalogue()
