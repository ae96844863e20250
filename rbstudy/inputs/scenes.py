"""Reading scenes: the ``scene:`` block of a study (docs/config.md) -> a checked
`rbstudy.physics.scenes.SceneTable`.

The scenes of a sweep share one mapping whose swept leaves are columns (numpy arrays, one
entry per scene): `scene_table` reads and checks them all at once, and one scene is a table of
one (`scene_from_mapping`): there is one reader. Non-physical input is rejected with a
`SceneError` naming the source, the key path, the value and the fix, on the first bad row of a
column. The body comes from ``scene.body`` or is assembled from nodes (`rbstudy.inputs.assembly`);
the loads are read by `rbstudy.inputs.loads`. A body on a pivot (``scene.pivot``) is the body
about that point: its inertia taken there, its nodes and loads seen from it (`_about_pivot`).

Frames: when the inertia is given as a full 3x3 tensor, the body vectors of the input
(angular velocity in body axes, node offsets, body loads) are in that tensor's frame; the
scene turns them into the principal frame, and the orientation it stores is the principal
frame's (``R_principal = R_input V`` with ``V`` the principal axes as columns, det +1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from rbstudy.errors import SceneError
from rbstudy.inputs.assembly import Secondaries, read_assembly
from rbstudy.inputs.columns import in_principal, one_row_if_alike, refuse, rows, symmetric_tensor
from rbstudy.inputs.loads import read_loads
from rbstudy.inputs.node_table import RESERVED
from rbstudy.inputs.reader import Reader
from rbstudy.physics.assembly import REGULARISATION, Assembly
from rbstudy.physics.scenes import Scene, SceneTable, triangle_ok

__all__ = ["scene_table", "scene_from_mapping"]

_ORIENTATION_FORMS = ("euler_zxz_deg", "quaternion", "rotation_vector", "momentum_axis")


@dataclass(frozen=True)
class _MassModel:
    """What ``scene.body`` and ``scene.nodes``, or ``scene.assembly``, give of a column of
    ``size`` bodies: mass (n,), principal inertias (n, 3), principal axes (n, 3, 3) or None
    when principal inertias were given, whether an unphysical body is allowed, the node names
    (N,) and offsets (n, N, 3) in the input body frame, the warnings, and for an assembled
    body its `Assembly` and `Secondaries` (else None)."""

    mass: np.ndarray
    inertia: np.ndarray
    axes: np.ndarray | None
    allow_unphysical: bool
    names: tuple[str, ...]
    offsets: np.ndarray
    warnings: tuple[str, ...]
    assembled: Assembly | None = None
    secondaries: Secondaries | None = None


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
            ~triangle_ok(inertia),
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


def _read_assembled(reader: Reader, spec: dict[str, Any], path: str, size: int) -> _MassModel:
    """The `_MassModel` of ``scene.assembly`` (`rbstudy.inputs.assembly`): its `Assembly` and
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
    return _MassModel(
        mass=body.mass,
        inertia=inertia,
        axes=axes,
        allow_unphysical=True,  # Radioss warns of a lopsided body rather than refusing it
        names=nodes.names,
        offsets=body.offsets,
        warnings=tuple(warnings),
        assembled=body,
        secondaries=nodes,
    )


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


def _about_pivot(
    reader: Reader, body: _MassModel, value: Any, key: str, size: int
) -> tuple[_MassModel, np.ndarray]:
    """The body of ``scene.pivot`` (``value`` at ``key``: the fixed point as an offset from the
    centre of mass in body axes, m, or a node's name) as it turns about that point: its
    inertia taken there (``J_c + m (|p|^2 1 - p p^T)``, principal axes anew) and the nodes'
    offsets from it; and the pivot ``p`` (n, 3) in the input body frame."""
    if body.assembled is not None:
        reader.fail(key, "an assembled body has no pivot here", "give scene.body with a pivot")
    if isinstance(value, str):
        if value not in body.names:
            reader.fail(
                key, f"no node {value!r} in scene.nodes", "name a node of scene.nodes, or give [x, y, z]"
            )
        pivot = np.array(body.offsets[:, body.names.index(value)])
    else:
        pivot = rows(reader.vector(value, key), size)
    tensor = (
        body.inertia[:, :, None] * np.eye(3)
        if body.axes is None
        else np.einsum("nij,nj,nkj->nik", body.axes, body.inertia, body.axes)
    )
    square = np.einsum("ni,ni->n", pivot, pivot)
    tensor = tensor + body.mass[:, None, None] * (
        square[:, None, None] * np.eye(3) - pivot[:, :, None] * pivot[:, None, :]
    )
    inertia, axes = _principal(reader, tensor, key)
    return replace(body, inertia=inertia, axes=axes, offsets=body.offsets - pivot[:, None, :]), pivot


def _read_mass_model(reader: Reader, spec: dict[str, Any], path: str, size: int) -> _MassModel:
    """The `_MassModel` of the scene mapping ``spec``, assembled or given."""
    if "assembly" in spec:
        return _read_assembled(reader, spec, path, size)
    mass, inertia, axes, allow = _read_body(reader, spec.get("body"), f"{path}.body", size)
    names, offsets = _read_nodes(reader, spec.get("nodes"), f"{path}.nodes", size)
    return _MassModel(
        mass=mass,
        inertia=inertia,
        axes=axes,
        allow_unphysical=allow,
        names=names,
        offsets=offsets,
        warnings=(),
    )


def _read_angular_velocity(
    reader: Reader, initial: dict[str, Any], path: str, inertia: np.ndarray, size: int
) -> dict[str, np.ndarray]:
    """The initial angular velocity (n, 3) by the frame it is given in (``body`` or ``space``,
    at most one), refused where the body's energy would overflow a float."""
    omega = reader.mapping(initial.get("angular_velocity"), path, ("body", "space"))
    if len(omega) > 1:
        reader.fail(path, "give the angular velocity in body or in space axes, not both")
    given = {frame: rows(reader.vector(omega[frame], f"{path}.{frame}"), size) for frame in omega}
    for frame, vector in given.items():
        with np.errstate(over="ignore"):  # |w|^2 max(I) bounds twice the energy
            energy = np.einsum("ni,ni->n", vector, vector) * inertia.max(axis=-1)
        refuse(
            reader,
            ~np.isfinite(energy),
            f"{path}.{frame}",
            lambda row: "so large that the body's energy overflows a float",
            "give a smaller angular velocity",
        )
    return given


def _read_attitude(
    reader: Reader, initial: dict[str, Any], path: str, body: _MassModel, size: int
) -> tuple[Rotation, np.ndarray]:
    """The initial orientation of the principal frame (a `Rotation` of ``size``) and angular
    velocity in principal axes (n, 3), from the mapping ``initial`` at ``path``."""
    given = _read_angular_velocity(reader, initial, f"{path}.angular_velocity", body.inertia, size)
    axes = body.axes
    omega_principal = in_principal(axes, given["body"]) if "body" in given else np.zeros((size, 3))
    # m = I w in the input body frame, for a momentum-aligned orientation
    momentum_input = (
        None
        if "body" not in given
        else omega_principal * body.inertia
        if axes is None
        else np.einsum("nij,nj->ni", axes, omega_principal * body.inertia)
    )
    input_rotation = _read_orientation(
        reader, initial.get("orientation"), f"{path}.orientation", momentum_input, size
    )
    principal_rotation = input_rotation if axes is None else input_rotation * Rotation.from_matrix(axes)
    if "space" in given:
        omega_principal = principal_rotation.inv().apply(given["space"])
    return principal_rotation, omega_principal


def scene_table(spec: Any, source: str = "<scene>", path: str = "scene", size: int = 1) -> SceneTable:
    """Build a `SceneTable` of ``size`` scenes from one mapping such as the ``scene:`` block
    of a study YAML, whose swept leaves are columns of ``size`` (module docstring).

    Raises `SceneError` for unknown keys, wrong types, non-finite numbers, non-positive mass
    or inertia, and inertias that violate the triangle inequality (unless
    ``body.allow_unphysical`` is true), on the first bad row of a column (its ``row``).
    """
    reader = Reader(source, SceneError)
    spec = reader.mapping(spec, path, ("body", "assembly", "initial", "nodes", "pivot", "loads", "duration"))
    body = _read_mass_model(reader, spec, path, size)
    pivot = None
    if "pivot" in spec:
        body, pivot = _about_pivot(reader, body, spec["pivot"], f"{path}.pivot", size)
    assembled, axes = body.assembled, body.axes
    nodes = in_principal(axes, body.offsets)

    initial_path = f"{path}.initial"
    initial = reader.mapping(
        spec.get("initial"), initial_path, ("angular_velocity", "orientation", "position", "velocity")
    )
    principal_rotation, omega_principal = _read_attitude(reader, initial, initial_path, body, size)
    if pivot is not None and "velocity" in initial:
        reader.fail(
            f"{initial_path}.velocity", "a body on a pivot does not translate", f"remove it (or {path}.pivot)"
        )

    points = dict(zip(body.names, np.moveaxis(nodes, 1, 0), strict=True))
    first_moment = held = None
    if assembled is not None:
        points[RESERVED] = in_principal(axes, assembled.master_offset[:, None, :])[:, 0]
        first_moment = in_principal(axes, assembled.first_moment[:, None, :])[:, 0]
    if pivot is not None:  # the centre of mass, seen from the pivot, carries the weight
        held = in_principal(axes, -pivot[:, None, :])[:, 0]
        first_moment = body.mass[:, None] * held
    loads, load_files = read_loads(
        reader, spec.get("loads"), f"{path}.loads", points, axes, first_moment, size, held
    )
    tables = (() if body.secondaries is None else body.secondaries.tables) + load_files
    return SceneTable(
        mass=_shared(body.mass),
        inertia=_shared(body.inertia),
        allow_unphysical=body.allow_unphysical,
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
        loads={name: _shared(column) for name, column in loads.items()},
        nodes=_shared(nodes),
        node_names=body.names,
        # not sweepable (`rbstudy.pipeline.grid`): one number, never a column
        duration=float(reader.number(spec.get("duration", 1.0), f"{path}.duration", positive=True)),
        warnings=body.warnings,
        regularised=None if assembled is None else assembled.regularised,
        tables=tables,
    )


def _shared(column):
    """``column`` (n, ...), or its first row seen n times (a read-only view) when every row is
    that row: the loads, nodes and initial motion a sweep leaves alone took 330 MiB of a
    million scenes. A column already seen so (stride 0) is left as it is."""
    row = one_row_if_alike(column) if column.strides[0] else column
    return column if row is column else np.broadcast_to(row.copy(), column.shape)  # not a view


def scene_from_mapping(spec: Any, source: str = "<scene>", path: str = "scene") -> Scene:
    """Build one `Scene` from a mapping such as the ``scene:`` block of a study YAML (see
    `scene_table`: a table of one)."""
    return scene_table(spec, source, path).scene(0)
