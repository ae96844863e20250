"""Scenes: a rigid body, its initial state, nodes fixed to it, loads and a duration.

A scene is read from a mapping (the ``scene:`` block of a study YAML, see docs/config.md) into
a frozen `Scene` that holds everything in the principal body frame, SI units, ready to become
one state row and one parameter row (`rbstudy.numerics.state`). Non-physical input is
rejected with a `SceneError` naming the source, the key path, the value and the fix.

The scenes of a sweep share one mapping whose swept leaves are columns (numpy arrays, one
entry per scene): `scene_table` reads and checks them all at once into a `SceneTable`, whose
``scene(i)`` is the i-th `Scene`. One scene is a table of one: there is one reader.

Frames: when the inertia is given as a full 3x3 tensor, the body vectors of the input
(angular velocity in body axes, node offsets, body loads) are in that tensor's frame; the
scene turns them into the principal frame, and the orientation it stores is the principal
frame's (``R_principal = R_input V`` with ``V`` the principal axes as columns, det +1).
"""

import math
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from rbstudy.errors import SceneError
from rbstudy.numerics import state as S
from rbstudy.numerics.loads import KIND, LOAD_KINDS
from rbstudy.physics.analytic import reference_kinds, symmetrised, symmetry_axes, symmetry_axis
from rbstudy.physics.assembly import REGULARISATION, read_assembly
from rbstudy.physics.columns import file_bindings, read_files, refuse, rows, symmetric_tensor
from rbstudy.physics.load_table import inline_load_table, read_load_file
from rbstudy.physics.loads import (
    GIVEN,
    TABLES,
    TABULATED,
    Loads,
    moving,
    record_slice,
    timed,
    turning,
)
from rbstudy.physics.node_table import RESERVED
from rbstudy.reader import Reader

__all__ = [
    "Body",
    "Loads",
    "Scene",
    "SceneTable",
    "scene_table",
    "scene_from_mapping",
    "param_rows",
    "TRIANGLE_RTOL",
]

# Inertias that meet the triangle inequality with equality (the thin flat disk I3 = I1 + I2 of
# the Abaqus benchmark) are physical; this relative slack absorbs the round-off of a
# diagonalised tensor so that such limit bodies are not rejected.
TRIANGLE_RTOL = 1e-9

_ORIENTATION_FORMS = ("euler_zxz_deg", "quaternion", "rotation_vector", "momentum_axis")
# The kinds that may act at a node (`_add_nodal_loads`), and those given in body axes (turned
# into the principal frame with the body's other vectors).
_NODAL_LOADS = tuple(kind.name for kind in LOAD_KINDS if kind.at_nodes)
_IN_BODY_AXES = tuple(kind.name for kind in LOAD_KINDS if kind.frame == "body")


@dataclass(frozen=True)
class Body:
    """Mass (kg) and principal inertias (3,) in kg m^2; ``regularised`` when an assembled
    body's smallest inertia was raised (`rbstudy.physics.assembly.REGULARISATION`)."""

    mass: float
    inertia: tuple
    allow_unphysical: bool = False
    regularised: bool = False

    @property
    def physical(self):
        """True when the principal inertias meet the triangle inequalities."""
        return bool(_triangle_ok(np.array(self.inertia)))

    def __post_init__(self):
        # symmetry is decided once (`rbstudy.physics.analytic.symmetry_axis`); a symmetric
        # body's two transverse moments are made exactly equal here, so that the integrated
        # body and its closed form are the same body
        object.__setattr__(self, "inertia", tuple(symmetrised(self.inertia).tolist()))

    @cached_property
    def symmetry_axis(self):
        """Index (0, 1, 2) of the symmetry axis of a symmetric body, or None (decided once per
        body: the outputs ask it of every case several times).

        Two principal inertias equal within `rbstudy.physics.analytic.SYMMETRY_RTOL` make the
        third axis the symmetry axis; a spherical body reports axis 2.
        """
        return symmetry_axis(self.inertia)


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
    def translates(self):
        """True when the centre of mass moves (initial velocity or a force)."""
        return bool(moving(self.velocity, vars(self.loads)))

    def state_row(self):
        """The initial state as a (N_STATE,) row (see `rbstudy.numerics.state`)."""
        row = np.zeros(S.N_STATE)
        for name, place in S.STATE_FIELDS.items():
            row[place] = getattr(self, name)
        return row

    def param_row(self):
        """The parameters as a row of `rbstudy.numerics.state.row_width` (N_PARAM when no
        load is tabulated in time; see `rbstudy.numerics.state`)."""
        loads = self.loads
        count = len(loads.knots)
        row = np.zeros(S.row_width(count))
        row[S.MASS] = self.body.mass
        row[S.INERTIA : S.INERTIA + 3] = self.body.inertia
        for kind in LOAD_KINDS:
            row[kind.offset : kind.offset + kind.width] = getattr(loads, kind.name)
        row[S.KNOTS] = count
        row[S.N_PARAM : S.N_PARAM + count] = loads.knots
        row[S.N_PARAM + count :] = np.reshape(loads.tabulated, -1)
        return row

    def with_changes(self, **changes):
        """A copy with some fields replaced (used by sweeps and tests)."""
        return replace(self, **changes)


@dataclass(frozen=True)
class SceneTable:
    """Scenes of one structure (the same keys, node names and duration), read and checked at
    once: the distinct scenes of a sweep. ``scene(i)`` is the i-th as a `Scene`.

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
    regularised: np.ndarray = None
    tables: tuple = ()

    def __len__(self):
        return len(self.mass)

    def scene(self, i):
        """The scene of row ``i``."""
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
            loads=Loads(
                **{
                    name: column[i] if name in TABLES else tuple(column[i].tolist())
                    for name, column in self.loads.items()
                }
            ),
            duration=self.duration,
        )

    @cached_property
    def symmetry_axes(self):
        """(n,) the symmetry axis of each body, -1 for an asymmetric one
        (`rbstudy.physics.analytic.symmetry_axes`)."""
        return symmetry_axes(symmetrised(self.inertia))  # as each Body decides it

    @cached_property
    def reference_kinds(self):
        """(n,) the reference of each scene (`rbstudy.physics.analytic.reference_kinds`)."""
        return reference_kinds(self.inertia, self.omega_body, self.loads, timed(self.loads))

    @cached_property
    def moment_free(self):
        """(n,) True where no moment acts."""
        return ~turning(self.loads)

    @cached_property
    def translates(self):
        """(n,) True where the centre of mass moves (initial velocity or a force)."""
        return moving(self.velocity, self.loads)


def param_rows(scenes):
    """The parameter rows of ``scenes``, (n, W) with W the widest row's width: each row is
    zero past its own width (`rbstudy.numerics.state.row_width`)."""
    rows_ = [scene.param_row() for scene in scenes]
    table = np.zeros((len(rows_), max((len(row) for row in rows_), default=S.N_PARAM)))
    for k, row in enumerate(rows_):
        table[k, : len(row)] = row
    return table


def _triangle_ok(inertia):
    """Whether principal inertias (..., 3) meet the triangle inequalities: a bool, or (...,)."""
    i1, i2, i3 = np.moveaxis(inertia, -1, 0)
    slack = TRIANGLE_RTOL * (i1 + i2 + i3)
    return (i1 + i2 >= i3 - slack) & (i2 + i3 >= i1 - slack) & (i3 + i1 >= i2 - slack)


def _in_principal(axes, vectors):
    """Input-frame vectors (n, ..., 3) in the principal frame (``axes`` (n, 3, 3) as columns,
    None for the identity); either may have one row for all n."""
    if axes is None:
        return vectors
    turn = axes.reshape(axes.shape[:1] + (1,) * (vectors.ndim - 2) + (3, 3))
    return (vectors[..., None, :] @ turn)[..., 0, :]


def _principal(reader, tensor, key):
    """Principal inertias (n, 3), ascending, and right-handed principal axes (n, 3, 3) as
    columns, of inertia tensors (n, 3, 3)."""
    inertia, axes = np.linalg.eigh(tensor)
    axes[np.linalg.det(axes) < 0, :, 2] *= -1.0
    refuse(
        reader,
        inertia.min(axis=-1) <= 0.0,
        key,
        lambda row: f"principal inertias must be > 0, got {[round(v, 12) for v in inertia[row].tolist()]}",
    )
    return inertia, axes


def _read_body(reader, spec, path, size):
    """mass (n,), principal inertias (n, 3), principal axes (n, 3, 3) (None when principal
    inertias were given) and the allow_unphysical flag."""
    spec = reader.mapping(spec, path, ("mass", "inertia", "allow_unphysical"))
    if "inertia" not in spec:
        reader.fail(f"{path}.inertia", "missing", "give principal inertias [I1, I2, I3] in kg m^2")
    mass = np.broadcast_to(reader.number(spec.get("mass", 1.0), f"{path}.mass", positive=True), (size,))
    allow = reader.flag(spec.get("allow_unphysical", False), f"{path}.allow_unphysical")
    raw = spec["inertia"]
    key = f"{path}.inertia"
    if isinstance(raw, (list, tuple)) and len(raw) == 3 and all(isinstance(r, (list, tuple)) for r in raw):
        inertia, axes = _principal(reader, symmetric_tensor(reader, raw, key, size), key)
    else:
        inertia = rows(reader.vector(raw, key), size)
        axes = None
        for i, moments in enumerate(inertia.T):
            refuse(
                reader,
                moments <= 0.0,
                f"{key}[{i}]",
                lambda row, moments=moments: f"must be > 0 kg m^2, got {float(moments[row])!r}",
            )
    if not allow:
        refuse(
            reader,
            ~_triangle_ok(inertia),
            key,
            lambda row: (
                f"{inertia[row].tolist()} violates the triangle inequality I1 + I2 "
                ">= I3 (and cyclic): no rigid body has it"
            ),
            "set allow_unphysical: true for a numerical stress body",
        )
    return mass, inertia, axes, allow


# What an assembled body derives from its nodes, never given twice: key -> why.
_DERIVED = {
    "body": "an assembled body's mass and inertia come from its nodes",
    "nodes": "an assembled body's nodes are its assembly.nodes",
    "initial.orientation": "an assembled body starts in the principal axes of its nodes",
    "initial.position": "an assembled body starts at the centre of mass of its nodes",
}


def _read_assembled(reader, spec, path, size):
    """The body of ``scene.assembly`` (`rbstudy.physics.assembly`): its `Assembly`, its
    `Secondaries`, principal inertias (n, 3) and axes (n, 3, 3), and the warnings."""
    for given, why in _DERIVED.items():
        parent, _, leaf = given.rpartition(".")
        if leaf in ((spec.get(parent) or {}) if parent else spec):
            reader.fail(f"{path}.{given}", f"{why}", f"remove {path}.{given}")
    key = f"{path}.assembly"
    body, nodes = read_assembly(reader, spec["assembly"], key, size)
    inertia, axes = _principal(reader, body.tensor, key)
    warnings = []
    if body.regularised.any():
        warnings.append(
            f"{key}: a principal inertia below {REGULARISATION:g} of the largest "
            f"was raised to it in {int(body.regularised.sum())} of {size} scenes "
            "(Radioss regularisation)"
        )
    if body.lopsided.any():
        warnings.append(
            f"{key}: one principal inertia exceeds the sum of the other two in "
            f"{int(body.lopsided.sum())} of {size} scenes (no rigid body of point "
            "masses has that: check the nodal inertias)"
        )
    return body, nodes, inertia, axes, tuple(warnings)


def _read_orientation(reader, spec, path, body_momentum, size):
    """The orientations of the input body frames, a `Rotation` of ``size``."""
    spec = reader.mapping(spec, path, _ORIENTATION_FORMS + ("phi_deg",))
    forms = [key for key in _ORIENTATION_FORMS if key in spec]
    if len(forms) > 1:
        reader.fail(path, f"give one orientation form, got {', '.join(forms)}")
    if "phi_deg" in spec and forms != ["momentum_axis"]:
        reader.fail(f"{path}.phi_deg", "only goes with momentum_axis")
    if not forms:
        return Rotation.identity(size)
    form = forms[0]
    key = f"{path}.{form}"
    if form == "euler_zxz_deg":
        return Rotation.from_euler("ZXZ", rows(reader.vector(spec[form], key), size), degrees=True)
    if form == "quaternion":
        quaternion = rows(reader.vector(spec[form], key, length=4), size)
        refuse(
            reader,
            np.linalg.norm(quaternion, axis=-1) == 0.0,
            key,
            lambda row: "a zero quaternion is no rotation",
        )
        return Rotation.from_quat(quaternion)
    if form == "rotation_vector":
        return Rotation.from_rotvec(rows(reader.vector(spec[form], key), size))
    axis = rows(reader.vector(spec[form], key), size)
    refuse(
        reader,
        np.linalg.norm(axis, axis=-1) == 0.0,
        key,
        lambda row: "the momentum axis must be a non-zero vector",
    )
    if body_momentum is None:
        reader.fail(key, "needs the angular velocity in body axes (initial.angular_velocity.body)")
    phi = reader.number(spec.get("phi_deg", 0.0), f"{path}.phi_deg")
    return _momentum_aligned(body_momentum, axis, phi)


def _momentum_aligned(body_momentum, axis, phi_deg=0.0):
    """The orientations that put ``L = R m`` along the space ``axis`` (the Abaqus set-up).

    ``body_momentum`` (n, 3) is ``m = I w`` in body axes; ``axis`` (n, 3) or (3,);
    ``phi_deg`` a number or (n,). Returns a `Rotation` of n.

    In z-x-z Euler angles about the momentum direction: ``theta = acos(m3/|m|)``,
    ``psi = atan2(m1, m2)``, ``phi`` free (default 0); then the frame is turned so that the
    space z axis goes to ``axis``. For the Abaqus top this gives (0, 1.1397 deg, 90 deg).
    """
    m = np.asarray(body_momentum, dtype=float)
    largest = np.abs(m).max(axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = np.where(largest > 0.0, m / largest, 0.0)  # scaled: a tiny m does not underflow
        size = np.linalg.norm(m, axis=-1)
        at_rest = size == 0.0  # no tilt, no turn
        theta = np.where(at_rest, 0.0, np.arccos(np.clip(m[:, 2] / size, -1.0, 1.0)))
    psi = np.where(at_rest, 0.0, np.arctan2(m[:, 0], m[:, 1]))
    phi = np.broadcast_to(np.radians(phi_deg), theta.shape)
    in_z = Rotation.from_euler("ZXZ", np.stack([phi, theta, psi], axis=-1))
    return _align_z(np.broadcast_to(np.asarray(axis, dtype=float), m.shape)) * in_z


def _align_z(axis):
    """The smallest rotations taking the space z axis to each ``axis`` (n, 3) (a target within
    `numpy.isclose` of +z is the identity, of -z a half turn about x)."""
    target = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    z = np.array([0.0, 0.0, 1.0])
    up = np.all(np.isclose(target, z), axis=-1)
    down = np.all(np.isclose(target, -z), axis=-1)
    turn = np.cross(z, target)
    length = np.linalg.norm(turn, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        rotvec = turn / length * np.arccos(np.clip(target[:, 2:], -1.0, 1.0))
    rotvec[up] = 0.0
    rotvec[down] = (math.pi, 0.0, 0.0)
    return Rotation.from_rotvec(rotvec)


def _read_nodes(reader, spec, path, size):
    """Node names (N,) and offsets (n, N, 3) in the input body frame."""
    if spec is None:
        return (), np.zeros((size, 0, 3))
    if not isinstance(spec, dict):
        reader.fail(path, f"expected a mapping of node name -> [x, y, z] offset in m, got {spec!r}")
    names = tuple(str(name) for name in spec)
    offsets = [rows(reader.vector(v, f"{path}.{k}"), size) for k, v in spec.items()]
    return names, np.stack(offsets, axis=1) if offsets else np.zeros((size, 0, 3))


def _lever(offsets, forces):
    """The `Loads.lever` of space ``forces`` (n, ..., 3) at principal ``offsets`` (n, 3): the
    rows ``d[b] F`` of ``d F^T``, (n, ..., 9) (either may have one row for all n)."""
    product = _along(offsets, forces)[..., :, None] * forces[..., None, :]
    return product.reshape(product.shape[:-2] + (9,))


def _alike(array):
    """``array`` (n, ...) as one row when every row equals the first (the scenes share it),
    else as it is: loads tabulated at K knots are then computed once, not n times."""
    if array is None or len(array) <= 1 or not (array == array[:1]).all():
        return array
    return array[:1]


def _along(offsets, vectors):
    """``offsets`` (n, 3) shaped to broadcast against ``vectors`` (n, ..., 3)."""
    return offsets.reshape(offsets.shape[:1] + (1,) * (vectors.ndim - 2) + (3,))


@dataclass(frozen=True)
class _Timed:
    """A load tabulated in time in n scenes: the distinct `LoadTable`s, which one each scene
    takes (n,), the scale (n,) of its values, and the table files read
    (`rbstudy.physics.columns.file_bindings`; none for a table given inline)."""

    tables: list
    index: np.ndarray
    scale: np.ndarray
    files: tuple = ()

    def at(self, knots):
        """The load (n, K, 3) at ``knots`` (K,); (1, K, 3) when the scenes share it."""
        values = np.stack([table.at(knots) for table in self.tables])[_alike(self.index)]
        return values * _alike(self.scale)[:, None, None]


def _read_timed(reader, spec, key, size):
    """The `_Timed` load of ``{table: rows or file, scale: s}`` at ``key``."""
    spec = reader.mapping(spec, key, ("table", "scale"))
    if "table" not in spec:
        reader.fail(
            f"{key}.table",
            "missing",
            "give rows [t, x, y, z] or a table file, or a constant [x, y, z] for the load",
        )
    scale = np.broadcast_to(reader.number(spec.get("scale", 1.0), f"{key}.scale"), (size,))
    table = spec["table"]
    if isinstance(table, list):
        return _Timed([inline_load_table(reader, table, f"{key}.table")], np.zeros(size, int), scale)
    names, tables, index = read_files(
        reader, table, f"{key}.table", size, read_load_file, "rows [t, x, y, z] or a load table file"
    )
    return _Timed(tables, index, scale, file_bindings(f"{key}.table", names, tables))


def _loaded_nodes(reader, spec, path, points):
    """The loads at nodes ``spec`` (node name -> {force_space, ...}, at ``path``), checked:
    ``(key, node name, its loads)`` for each node, which must be one of ``points``."""
    if not isinstance(spec, dict):
        reader.fail(path, f"expected a mapping of node name -> loads, got {spec!r:.80}")
    if len({str(name) for name in spec}) < len(spec):  # 56 and "56" in the YAML
        reader.fail(path, "a node is loaded twice (as a number and as text)", "load it once")
    checked = []
    for name, node_spec in spec.items():
        key = f"{path}.{name}"
        if str(name) not in points:
            reader.fail(
                key,
                "no such node in this body",
                "load a node of the scene's nodes (or master, for an assembled body)",
            )
        checked.append((key, str(name), reader.mapping(node_spec, key, _NODAL_LOADS)))
    return checked


def _timed_loads(reader, spec, path, nodal, size):
    """The loads tabulated in time under ``scene.loads`` (``spec``, at ``path``), at the
    centre and at the ``nodal`` loads (`_loaded_nodes`): key -> `_Timed`."""
    found = {f"{path}.{name}": spec[name] for name in TABULATED if isinstance(spec.get(name), dict)}
    found.update(
        {
            f"{key}.{name}": value
            for key, _, node_loads in nodal
            for name, value in node_loads.items()
            if isinstance(value, dict)
        }
    )
    return {key: _read_timed(reader, value, key, size) for key, value in found.items()}


class _LoadSets:
    """The loads of n scenes while they are read: the constant ones (name -> (n, 3), (n, 9)
    for the lever) and those tabulated in time at the ``knots`` (K,) (name -> (n, K, 3),
    (n, K, 9), or one row (1, K, ...) while every scene has the same), each added to as it
    is read."""

    def __init__(self, reader, timed, size):
        self.reader, self.timed, self.size = reader, timed, size
        self.knots = np.unique(
            np.concatenate([np.zeros(0)] + [table.times for load in timed.values() for table in load.tables])
        )
        self.constant = {kind.name: np.zeros((size, kind.width)) for kind in LOAD_KINDS}
        self.tabulated = {name: np.zeros((1, len(self.knots), KIND[name].width)) for name in TABULATED}

    def read(self, value, key):
        """The load at ``key``, constant (n, 3) or tabulated at the knots (n or 1, K, 3)."""
        if key in self.timed:
            return self.timed[key].at(self.knots)
        return rows(self.reader.vector(value, key), self.size)

    def add(self, name, value):
        """Add ``value`` ((n, w) or (n or 1, K, w), as `read` gives it) to the load ``name``."""
        loads = self.constant if value.ndim == 2 else self.tabulated
        loads[name] = loads[name] + value

    def columns(self):
        """The `SceneTable.loads` columns: the constant loads, the knots and the records
        (read-only views, of one row when every scene has the same)."""
        shape = (self.size, len(self.knots))
        record = np.zeros((max(len(value) for value in self.tabulated.values()), shape[1], S.LOAD_RECORD))
        for name, values in self.tabulated.items():
            record[..., record_slice(name)] = values
        record.setflags(write=False)  # each scene's `Loads` holds a view of it
        return {
            **self.constant,
            "knots": np.broadcast_to(self.knots, shape),
            "tabulated": np.broadcast_to(record, shape + (S.LOAD_RECORD,)),
        }


def _add_nodal_loads(nodal, loads, points, axes):
    """Add the loads at nodes ``nodal`` (`_loaded_nodes`) to ``loads`` (a `_LoadSets`),
    aggregated to the centre of mass: ``F = sum F_i`` and ``M = sum M_i + sum d_i x F_i``
    with ``d_i`` the node's offset (``points``: name -> (n, 3), principal axes). A body-axis
    force gives a body moment; a space-axis force a moment that turns with the body (the
    lever, evaluated every step by the kernels). Constant and tabulated loads aggregate
    alike (each is linear in the nodal loads)."""
    for key, name, node_spec in nodal:
        offset = _alike(points[name])
        for load, value in node_spec.items():
            given = loads.read(value, f"{key}.{load}")
            if load in _IN_BODY_AXES:
                given = _in_principal(axes, given)
            loads.add(load, given)
            if load == "force_space":
                loads.add("lever", _lever(offset, given))
            elif load == "force_body":
                loads.add("moment_body", np.cross(_along(offset, given), given))


def scene_table(spec, source="<scene>", path="scene", size=1):
    """Build a `SceneTable` of ``size`` scenes from one mapping such as the ``scene:`` block
    of a study YAML, whose swept leaves are columns of ``size`` (module docstring).

    Raises `SceneError` for unknown keys, wrong types, non-finite numbers, non-positive mass
    or inertia, and inertias that violate the triangle inequality (unless
    ``body.allow_unphysical`` is true), on the first bad row of a column (its ``row``).
    """
    reader = Reader(source, SceneError)
    spec = reader.mapping(spec, path, ("body", "assembly", "initial", "nodes", "loads", "duration"))
    assembled = None
    if "assembly" in spec:
        assembled, secondaries, inertia, axes, warnings = _read_assembled(reader, spec, path, size)
        mass, names, offsets = assembled.mass, secondaries.names, assembled.offsets
        allow = True  # Radioss warns of a lopsided body rather than refusing it
    else:
        mass, inertia, axes, allow = _read_body(reader, spec.get("body"), f"{path}.body", size)
        names, offsets = _read_nodes(reader, spec.get("nodes"), f"{path}.nodes", size)
        warnings = ()
    nodes = _in_principal(axes, offsets)

    initial_path = f"{path}.initial"
    initial = reader.mapping(
        spec.get("initial"), initial_path, ("angular_velocity", "orientation", "position", "velocity")
    )
    omega_path = f"{initial_path}.angular_velocity"
    omega = reader.mapping(initial.get("angular_velocity"), omega_path, ("body", "space"))
    if len(omega) > 1:
        reader.fail(omega_path, "give the angular velocity in body or in space axes, not both")
    given = {frame: rows(reader.vector(omega[frame], f"{omega_path}.{frame}"), size) for frame in omega}
    for frame, vector in given.items():
        with np.errstate(over="ignore"):  # |w|^2 max(I) bounds twice the energy
            energy = np.einsum("ni,ni->n", vector, vector) * inertia.max(axis=-1)
        refuse(
            reader,
            ~np.isfinite(energy),
            f"{omega_path}.{frame}",
            lambda row: "so large that the body's energy overflows a float",
            "give a smaller angular velocity",
        )
    omega_principal = _in_principal(axes, given["body"]) if "body" in given else np.zeros((size, 3))
    # m = I w in the input body frame, for a momentum-aligned orientation
    momentum_input = (
        None
        if "body" not in given
        else omega_principal * inertia
        if axes is None
        else np.einsum("nij,nj->ni", axes, omega_principal * inertia)
    )
    input_rotation = _read_orientation(
        reader, initial.get("orientation"), f"{initial_path}.orientation", momentum_input, size
    )
    principal_rotation = input_rotation if axes is None else input_rotation * Rotation.from_matrix(axes)
    if "space" in given:
        omega_principal = principal_rotation.inv().apply(given["space"])

    loads_path = f"{path}.loads"
    loads_spec = reader.mapping(spec.get("loads"), loads_path, GIVEN + ("nodes",))
    points = dict(zip(names, np.moveaxis(nodes, 1, 0), strict=True))
    if assembled is not None:
        points[RESERVED] = _in_principal(axes, assembled.master_offset[:, None, :])[:, 0]
    nodal = (
        _loaded_nodes(reader, loads_spec["nodes"], f"{loads_path}.nodes", points)
        if "nodes" in loads_spec
        else []
    )
    loads = _LoadSets(reader, _timed_loads(reader, loads_spec, loads_path, nodal, size), size)
    for name in GIVEN:
        if name in loads_spec:
            key = f"{loads_path}.{name}"
            given = loads.read(loads_spec[name], key)
            if KIND[name].dissipates:  # a negative value would feed energy in
                refuse(
                    reader,
                    np.any(given.reshape(len(given), -1) < 0.0, axis=-1),
                    key,
                    lambda row, given=given: f"got {given[row].tolist()}, below 0",
                    f"give values >= 0 ({KIND[name].units}): it only takes energy out",
                )
            loads.add(name, _in_principal(_alike(axes), given) if name in _IN_BODY_AXES else given)
    if assembled is not None:
        # gravity pulls every mass point: about a centre that is not the centre of mass, its
        # moment is (sum m_j d_j) x g
        first_moment = _alike(_in_principal(axes, assembled.first_moment[:, None, :])[:, 0])
        for gravity in (loads.constant["gravity"], loads.tabulated["gravity"]):
            loads.add("lever", _lever(first_moment, gravity))
    _add_nodal_loads(nodal, loads, points, _alike(axes))
    tables = (() if assembled is None else secondaries.tables) + tuple(
        binding for load in loads.timed.values() for binding in load.files
    )
    return SceneTable(
        mass=_shared(mass),
        inertia=_shared(inertia),
        allow_unphysical=allow,
        quaternion=principal_rotation.as_quat().reshape(size, 4),
        omega_body=omega_principal,
        position=_shared(
            assembled.centre
            if assembled is not None
            else rows(reader.vector(initial.get("position", [0, 0, 0]), f"{initial_path}.position"), size)
        ),
        velocity=_shared(
            rows(reader.vector(initial.get("velocity", [0, 0, 0]), f"{initial_path}.velocity"), size)
        ),
        loads={name: _shared(column) for name, column in loads.columns().items()},
        nodes=_shared(nodes),
        node_names=names,
        duration=reader.number(spec.get("duration", 1.0), f"{path}.duration", positive=True),
        warnings=warnings,
        regularised=None if assembled is None else assembled.regularised,
        tables=tables,
    )


def _shared(column):
    """``column`` (n, ...), or its first row seen n times (a read-only view) when every row is
    that row: the loads, nodes and initial motion a sweep leaves alone took 330 MiB of a
    million scenes."""
    if len(column) > 1 and column.strides[0] and (column == column[:1]).all():
        return np.broadcast_to(column[:1].copy(), column.shape)  # not a view of the whole
    return column


def scene_from_mapping(spec, source="<scene>", path="scene"):
    """Build one `Scene` from a mapping such as the ``scene:`` block of a study YAML (see
    `scene_table`: a table of one)."""
    return scene_table(spec, source, path).scene(0)
