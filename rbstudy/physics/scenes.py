"""Scenes: a rigid body, its initial state, nodes fixed to it, loads and a duration.

A `Scene` holds everything in the principal body frame, SI units, ready to become one state
row and one parameter row (`rbstudy.numerics.state`). The scenes of a sweep are held as
columns, one entry per scene, in a `SceneTable`: the pipeline takes its state and parameter
rows straight from the columns (`SceneTable.batch_rows`), and
``scene(i)`` is the i-th as a `Scene`, the view tests and analysis take.

This is the data model only: `rbstudy.inputs.scenes` reads a ``scene:`` block of a study
(docs/config.md) into a checked `SceneTable`.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np

from rbstudy.errors import RbstudyError
from rbstudy.numerics import state as S
from rbstudy.numerics.loads import LOAD_KINDS
from rbstudy.physics.analytic import reference_kinds, symmetrised, symmetry_axes, symmetry_axis
from rbstudy.physics.loads import TABLES, Loads, moving, timed, turning

__all__ = [
    "Body",
    "Loads",
    "Scene",
    "SceneTable",
    "BatchRows",
    "batch_rows",
    "param_rows",
    "triangle_ok",
    "TRIANGLE_RTOL",
]

# Inertias that meet the triangle inequality with equality (the thin flat disk I3 = I1 + I2 of
# the Abaqus benchmark) are physical; this relative slack absorbs the round-off of a
# diagonalised tensor so that such limit bodies are not rejected.
TRIANGLE_RTOL = 1e-9


@dataclass(frozen=True)
class Body:
    """Mass (kg) and principal inertias (3,) in kg m^2; ``regularised`` when an assembled
    body's smallest inertia was raised (`rbstudy.physics.assembly.REGULARISATION`)."""

    mass: float
    inertia: tuple
    allow_unphysical: bool = False
    regularised: bool = False

    @property
    def physical(self) -> bool:
        """True when the principal inertias meet the triangle inequalities."""
        return bool(triangle_ok(np.array(self.inertia)))

    def __post_init__(self) -> None:
        # symmetry is decided once (`rbstudy.physics.analytic.symmetry_axis`); a symmetric
        # body's two transverse moments are made exactly equal here, so that the integrated
        # body and its closed form are the same body
        object.__setattr__(self, "inertia", tuple(symmetrised(self.inertia).tolist()))

    @cached_property
    def symmetry_axis(self) -> int | None:
        """Index (0, 1, 2) of the symmetry axis of a symmetric body, or None (decided once per
        body: the outputs ask it of every case several times).

        Two principal inertias equal within `rbstudy.physics.analytic.SYMMETRY_RTOL` make the
        third axis the symmetry axis; a spherical body reports axis 2.
        """
        return symmetry_axis(self.inertia)


class BatchRows(NamedTuple):
    """What the kernels integrate of m scenes: ``states`` (m, N_STATE) and ``params``
    (m, W) rows (`rbstudy.numerics.state`), and the ``duration`` (s) they all run."""

    states: np.ndarray
    params: np.ndarray
    duration: float


@dataclass(frozen=True)
class Scene:
    """A rigid body and everything needed to integrate it, in the principal frame, SI units.

    quaternion : (4,) scalar-last, maps principal body axes to space at t = 0.
    omega_body : (3,) rad/s in principal axes.  position, velocity : (3,) m, m/s.
    nodes : (N, 3) offsets from the centre of mass in principal axes (m); node_names : (N,).
    """

    body: Body
    quaternion: tuple
    omega_body: tuple
    position: tuple = (0.0, 0.0, 0.0)
    velocity: tuple = (0.0, 0.0, 0.0)
    nodes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), compare=False)
    node_names: tuple = ()
    loads: Loads = Loads()
    duration: float = 1.0

    @property
    def translates(self) -> bool:
        """True when the centre of mass moves (initial velocity or a force)."""
        return bool(moving(self.velocity, vars(self.loads)))

    def state_row(self) -> np.ndarray:
        """The initial state as a (N_STATE,) row (see `rbstudy.numerics.state`)."""
        return _state_rows({name: np.atleast_2d(getattr(self, name)) for name in S.STATE_FIELDS})[0]

    def param_row(self) -> np.ndarray:
        """The parameters as a row of `rbstudy.numerics.state.row_width` (N_PARAM when no
        load is tabulated in time; see `rbstudy.numerics.state`)."""
        loads = {name: np.asarray(value)[None] for name, value in vars(self.loads).items()}
        return _param_rows(np.array([self.body.mass]), np.array([self.body.inertia]), loads)[0]

    def with_changes(self, **changes: Any) -> Scene:
        """A copy with some fields replaced (used by sweeps and tests)."""
        return replace(self, **changes)


@dataclass(frozen=True)
class SceneTable:
    """Scenes of one structure (the same keys, node names and duration), read and checked at
    once: the distinct scenes of a sweep, as columns. The pipeline takes the rows the kernels
    integrate straight from the columns (`batch_rows`); ``scene(i)`` is the i-th as a
    `Scene`, the view tests and analysis take.

    mass : (n,) kg. inertia : (n, 3) principal, kg m^2, as read or diagonalised (each
    `Scene`'s `Body` symmetrises its own, once). quaternion : (n, 4).
    omega_body, position, velocity : (n, 3), as in `Scene`. loads : name of a `Loads` field ->
    (n, 3), (n, 9) for the lever, (n, K) knots and (n, K, LOAD_RECORD) tabulated.
    nodes : (n, N, 3). node_names : (N,). Columns a sweep leaves alone may be read-only
    broadcast views. warnings : what the reading noticed but accepted
    (a regularised assembled body), one line each. regularised : (n,) True where an
    assembled body's inertia was regularised, None for a body not assembled. tables : the
    node and load table files read, each as (key, file name, sha256 digest). What the scenes
    are (symmetry, reference, loads acting) is worked out once, when first asked.
    """

    mass: np.ndarray
    inertia: np.ndarray
    allow_unphysical: bool
    quaternion: np.ndarray
    omega_body: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    loads: dict
    nodes: np.ndarray
    node_names: tuple
    duration: float
    warnings: tuple = ()
    regularised: np.ndarray | None = None
    tables: tuple = ()

    def __len__(self) -> int:
        return len(self.mass)

    def scene(self, i: int) -> Scene:
        """The scene of row ``i``."""
        # a `Loads` field per kind, as tuples; the tables in time as arrays
        loads: dict[str, Any] = {
            name: column[i] if name in TABLES else tuple(column[i].tolist())
            for name, column in self.loads.items()
        }
        return Scene(
            body=Body(
                mass=float(self.mass[i]),
                inertia=tuple(self.inertia[i].tolist()),
                allow_unphysical=self.allow_unphysical,
                regularised=self.regularised is not None and bool(self.regularised[i]),
            ),
            quaternion=tuple(self.quaternion[i].tolist()),
            omega_body=tuple(self.omega_body[i].tolist()),
            position=tuple(self.position[i].tolist()),
            velocity=tuple(self.velocity[i].tolist()),
            nodes=np.array(self.nodes[i]),
            node_names=self.node_names,
            loads=Loads(**loads),
            duration=self.duration,
        )

    def batch_rows(self, rows: np.ndarray | Sequence[int]) -> BatchRows:
        """The `BatchRows` of the scenes ``rows`` (m,), taken from the columns: the rows each
        `Scene` packs (`Scene.state_row`, `Scene.param_row`: the inertias symmetrised as its
        `Body` does), with K the table's knots."""
        loads = {name: column[rows] for name, column in self.loads.items()}
        return BatchRows(
            states=_state_rows({name: getattr(self, name)[rows] for name in S.STATE_FIELDS}),
            params=_param_rows(self.mass[rows], symmetrised(self.inertia[rows]), loads),
            duration=self.duration,
        )

    @cached_property
    def timed(self) -> np.ndarray:
        """(n,) True where some load varies in time."""
        # of columns, the load tests give arrays already: asarray returns them as they are
        return np.asarray(timed(self.loads))

    @cached_property
    def symmetry_axes(self) -> np.ndarray:
        """(n,) the symmetry axis of each body, -1 for an asymmetric one
        (`rbstudy.physics.analytic.symmetry_axes`)."""
        return symmetry_axes(symmetrised(self.inertia))  # as each Body decides it

    @cached_property
    def reference_kinds(self) -> np.ndarray:
        """(n,) the reference of each scene (`rbstudy.physics.analytic.reference_kinds`)."""
        return reference_kinds(self.inertia, self.omega_body, self.loads, self.timed)

    @cached_property
    def moment_free(self) -> np.ndarray:
        """(n,) True where no moment acts."""
        return ~np.asarray(turning(self.loads))

    @cached_property
    def translates(self) -> np.ndarray:
        """(n,) True where the centre of mass moves (initial velocity or a force)."""
        return np.asarray(moving(self.velocity, self.loads))


def batch_rows(scenes: Sequence[Scene]) -> BatchRows:
    """The `BatchRows` of ``scenes`` (m,), all of one duration: each scene's
    `Scene.state_row`, and their `param_rows`."""
    durations = {scene.duration for scene in scenes}
    if len(durations) != 1:
        raise RbstudyError(f"a batch needs one duration, got {sorted(durations)}")
    return BatchRows(
        states=np.array([scene.state_row() for scene in scenes]),
        params=param_rows(scenes),
        duration=durations.pop(),
    )


def _state_rows(fields):
    """State rows (m, N_STATE) of ``fields``: each `rbstudy.numerics.state.STATE_FIELDS` name
    -> (m, width)."""
    table = np.zeros((len(fields["quaternion"]), S.N_STATE))
    for name, place in S.STATE_FIELDS.items():
        table[:, place] = fields[name]
    return table


def _param_rows(mass, inertia, loads):
    """Parameter rows (m, row_width(K)) of ``mass`` (m,) kg, principal ``inertia`` (m, 3)
    kg m^2 and ``loads``: each `Loads` field -> (m, width), ``knots`` (m, K) and
    ``tabulated`` (m, K, LOAD_RECORD) (the layout of `rbstudy.numerics.state`)."""
    count = loads["knots"].shape[-1]
    table = np.zeros((len(mass), S.row_width(count)))
    table[:, S.MASS] = mass
    table[:, S.INERTIA : S.INERTIA + 3] = inertia
    for kind in LOAD_KINDS:
        table[:, kind.offset : kind.offset + kind.width] = loads[kind.name]
    table[:, S.KNOTS] = count
    table[:, S.N_PARAM : S.N_PARAM + count] = loads["knots"]
    table[:, S.N_PARAM + count :] = loads["tabulated"].reshape(len(mass), count * S.LOAD_RECORD)
    return table


def param_rows(scenes: Iterable[Scene]) -> np.ndarray:
    """The parameter rows of ``scenes``, (n, W) with W the widest row's width: each row is
    zero past its own width (`rbstudy.numerics.state.row_width`)."""
    rows_ = [scene.param_row() for scene in scenes]
    table = np.zeros((len(rows_), max((len(row) for row in rows_), default=S.N_PARAM)))
    for k, row in enumerate(rows_):
        table[k, : len(row)] = row
    return table


def triangle_ok(inertia: np.ndarray) -> np.ndarray | np.bool_:
    """Whether principal inertias (..., 3) meet the triangle inequalities: a bool, or (...,)."""
    i1, i2, i3 = np.moveaxis(inertia, -1, 0)
    slack = TRIANGLE_RTOL * (i1 + i2 + i3)
    return (i1 + i2 >= i3 - slack) & (i2 + i3 >= i1 - slack) & (i3 + i1 >= i2 - slack)
