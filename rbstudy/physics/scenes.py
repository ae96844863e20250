"""Scenes: a rigid body, its initial state, nodes fixed to it, loads and a duration.

A scene is read from a mapping (the ``scene:`` block of a study YAML, see docs/config.md) into
a frozen `Scene` that holds everything in the principal body frame, SI units, ready to become
one state row and one parameter row (`rbstudy.numerics.state`). Non-physical input is
rejected with a `SceneError` naming the source, the key path, the value and the fix.

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
from rbstudy.physics.analytic import symmetrised, symmetry_axis
from rbstudy.reader import Reader

__all__ = ["Body", "Loads", "Scene", "scene_from_mapping", "momentum_aligned", "TRIANGLE_RTOL"]

# Inertias that meet the triangle inequality with equality (the thin flat disk I3 = I1 + I2 of
# the Abaqus benchmark) are physical; this relative slack absorbs the round-off of a
# diagonalised tensor so that such limit bodies are not rejected.
TRIANGLE_RTOL = 1e-9

_ORIENTATION_FORMS = ("euler_zxz_deg", "quaternion", "rotation_vector", "momentum_axis")


@dataclass(frozen=True)
class Body:
    """Mass (kg), principal inertias (3,) in kg m^2, and the principal axes (3, 3) as columns
    in the input body frame (identity when principal inertias were given)."""

    mass: float
    inertia: tuple
    axes: np.ndarray = field(default_factory=lambda: np.eye(3), compare=False)
    allow_unphysical: bool = False

    @property
    def physical(self):
        """True when the principal inertias meet the triangle inequalities."""
        return _triangle_ok(self.inertia)

    def __post_init__(self):
        # symmetry is decided once (`rbstudy.physics.analytic.symmetry_axis`); a symmetric
        # body's two transverse moments are made exactly equal here, so that the integrated
        # body and its closed form are the same body
        object.__setattr__(self, "inertia", symmetrised(self.inertia))

    @cached_property
    def symmetry_axis(self):
        """Index (0, 1, 2) of the symmetry axis of a symmetric body, or None (decided once per
        body: a sweep asks it of every case several times).

        Two principal inertias equal within `rbstudy.physics.analytic.SYMMETRY_RTOL` make the
        third axis the symmetry axis; a spherical body reports axis 2.
        """
        return symmetry_axis(self.inertia)


@dataclass(frozen=True)
class Loads:
    """Constant loads: forces (N) and moments (N m) in space or body axes, gravity (m/s^2)."""

    force_space: tuple = (0.0, 0.0, 0.0)
    force_body: tuple = (0.0, 0.0, 0.0)
    moment_space: tuple = (0.0, 0.0, 0.0)
    moment_body: tuple = (0.0, 0.0, 0.0)
    gravity: tuple = (0.0, 0.0, 0.0)

    @property
    def moment_free(self):
        return not any(self.moment_space) and not any(self.moment_body)

    @property
    def force_free(self):
        return not any(self.force_space) and not any(self.force_body) and not any(self.gravity)


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
        return any(self.velocity) or not self.loads.force_free

    def state_row(self):
        """The initial state as a (N_STATE,) row (see `rbstudy.numerics.state`)."""
        row = np.zeros(S.N_STATE)
        row[S.POSITION:S.POSITION + 3] = self.position
        row[S.QUATERNION:S.QUATERNION + 4] = self.quaternion
        row[S.VELOCITY:S.VELOCITY + 3] = self.velocity
        row[S.OMEGA:S.OMEGA + 3] = self.omega_body
        return row

    def param_row(self):
        """The parameters as a (N_PARAM,) row (see `rbstudy.numerics.state`)."""
        row = np.zeros(S.N_PARAM)
        row[S.MASS] = self.body.mass
        row[S.INERTIA:S.INERTIA + 3] = self.body.inertia
        loads = self.loads
        for offset, value in ((S.FORCE_SPACE, loads.force_space), (S.FORCE_BODY, loads.force_body),
                              (S.MOMENT_SPACE, loads.moment_space),
                              (S.MOMENT_BODY, loads.moment_body), (S.GRAVITY, loads.gravity)):
            row[offset:offset + 3] = value
        return row

    def with_changes(self, **changes):
        """A copy with some fields replaced (used by sweeps and tests)."""
        return replace(self, **changes)


def _triangle_ok(inertia):
    i1, i2, i3 = inertia
    slack = TRIANGLE_RTOL * (i1 + i2 + i3)
    return i1 + i2 >= i3 - slack and i2 + i3 >= i1 - slack and i3 + i1 >= i2 - slack


def _read_body(reader, spec, path):
    spec = reader.mapping(spec, path, ("mass", "inertia", "allow_unphysical"))
    if "inertia" not in spec:
        reader.fail(f"{path}.inertia", "missing", "give principal inertias [I1, I2, I3] in kg m^2")
    mass = reader.number(spec.get("mass", 1.0), f"{path}.mass", positive=True)
    allow = reader.flag(spec.get("allow_unphysical", False), f"{path}.allow_unphysical")
    raw = spec["inertia"]
    if isinstance(raw, (list, tuple)) and len(raw) == 3 and all(isinstance(r, (list, tuple)) for r in raw):
        tensor = np.array([reader.vector(row, f"{path}.inertia[{i}]") for i, row in enumerate(raw)])
        if not np.allclose(tensor, tensor.T, rtol=1e-12, atol=0.0):
            reader.fail(f"{path}.inertia", "the inertia tensor must be symmetric")
        values, axes = np.linalg.eigh(tensor)
        if np.linalg.det(axes) < 0:
            axes[:, 2] *= -1.0
        inertia = tuple(float(v) for v in values)
        if min(inertia) <= 0.0:
            reader.fail(f"{path}.inertia",
                        f"principal inertias must be > 0, got {[round(v, 12) for v in inertia]}")
    else:
        inertia = reader.vector(raw, f"{path}.inertia")
        axes = np.eye(3)
        for i, value in enumerate(inertia):
            if value <= 0.0:
                reader.fail(f"{path}.inertia[{i}]", f"must be > 0 kg m^2, got {value!r}")
    if not allow and not _triangle_ok(inertia):
        reader.fail(f"{path}.inertia",
                    f"{list(inertia)} violates the triangle inequality I1 + I2 >= I3 (and cyclic): "
                    "no rigid body has it", "set allow_unphysical: true for a numerical stress body")
    return Body(mass=mass, inertia=inertia, axes=axes, allow_unphysical=allow)


def _read_orientation(reader, spec, path, body_momentum):
    spec = reader.mapping(spec, path, _ORIENTATION_FORMS + ("phi_deg",))
    forms = [key for key in _ORIENTATION_FORMS if key in spec]
    if len(forms) > 1:
        reader.fail(path, f"give one orientation form, got {', '.join(forms)}")
    if "phi_deg" in spec and forms != ["momentum_axis"]:
        reader.fail(f"{path}.phi_deg", "only goes with momentum_axis")
    if not forms:
        return Rotation.identity()
    form = forms[0]
    key = f"{path}.{form}"
    if form == "euler_zxz_deg":
        return Rotation.from_euler("ZXZ", reader.vector(spec[form], key), degrees=True)
    if form == "quaternion":
        quaternion = np.array(reader.vector(spec[form], key, length=4))
        if np.linalg.norm(quaternion) == 0.0:
            reader.fail(key, "a zero quaternion is no rotation")
        return Rotation.from_quat(quaternion)
    if form == "rotation_vector":
        return Rotation.from_rotvec(reader.vector(spec[form], key))
    axis = np.array(reader.vector(spec[form], key))
    if np.linalg.norm(axis) == 0.0:
        reader.fail(key, "the momentum axis must be a non-zero vector")
    if body_momentum is None:
        reader.fail(key, "needs the angular velocity in body axes (initial.angular_velocity.body)")
    phi = reader.number(spec.get("phi_deg", 0.0), f"{path}.phi_deg")
    return momentum_aligned(body_momentum, axis, phi)


def momentum_aligned(body_momentum, axis, phi_deg=0.0):
    """The orientation that puts ``L = R m`` along the space ``axis`` (the Abaqus set-up).

    ``body_momentum`` (3,) is ``m = I w`` in body axes.

    In z-x-z Euler angles about the momentum direction: ``theta = acos(m3/|m|)``,
    ``psi = atan2(m1, m2)``, ``phi`` free (default 0); then the frame is turned so that the
    space z axis goes to ``axis``. For the Abaqus top this gives (0, 1.1397 deg, 90 deg).
    """
    m = np.asarray(body_momentum, dtype=float)
    size = np.linalg.norm(m)
    if size == 0.0:
        theta = psi = 0.0
    else:
        theta = math.acos(max(-1.0, min(1.0, m[2] / size)))
        psi = math.atan2(m[0], m[1])
    in_z = Rotation.from_euler("ZXZ", [math.radians(phi_deg), theta, psi])
    return _align_z(np.asarray(axis, dtype=float)) * in_z


def _align_z(axis):
    """The smallest rotation taking the space z axis to ``axis``."""
    target = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    if np.allclose(target, z):
        return Rotation.identity()
    if np.allclose(target, -z):
        return Rotation.from_rotvec([math.pi, 0.0, 0.0])
    turn = np.cross(z, target)
    return Rotation.from_rotvec(turn / np.linalg.norm(turn) * math.acos(np.clip(target[2], -1, 1)))


def _read_nodes(reader, spec, path):
    if spec is None:
        return (), np.zeros((0, 3))
    if not isinstance(spec, dict):
        reader.fail(path, f"expected a mapping of node name -> [x, y, z] offset in m, got {spec!r}")
    names = tuple(str(name) for name in spec)
    offsets = np.array([reader.vector(v, f"{path}.{k}") for k, v in spec.items()]).reshape(-1, 3)
    return names, offsets


def _energy_representable(body, omega):
    """True when ``|w|^2 max(I)``, a bound on twice the rotational energy, is a finite float."""
    with np.errstate(over="ignore"):
        return bool(np.isfinite(np.dot(omega, omega) * max(body.inertia)))


def scene_from_mapping(spec, source="<scene>", path="scene"):
    """Build a `Scene` from a mapping such as the ``scene:`` block of a study YAML.

    Raises `SceneError` for unknown keys, wrong types, non-finite numbers, non-positive mass
    or inertia, and inertias that violate the triangle inequality (unless
    ``body.allow_unphysical`` is true).
    """
    reader = Reader(source, SceneError)
    spec = reader.mapping(spec, path, ("body", "initial", "nodes", "loads", "duration"))
    body = _read_body(reader, spec.get("body"), f"{path}.body")
    to_principal = body.axes.T  # input body frame -> principal frame

    initial_path = f"{path}.initial"
    initial = reader.mapping(spec.get("initial"), initial_path,
                             ("angular_velocity", "orientation", "position", "velocity"))
    omega_path = f"{initial_path}.angular_velocity"
    omega = reader.mapping(initial.get("angular_velocity"), omega_path, ("body", "space"))
    if len(omega) > 1:
        reader.fail(omega_path, "give the angular velocity in body or in space axes, not both")
    omega_input = (np.array(reader.vector(omega["body"], f"{omega_path}.body"))
                   if "body" in omega else None)
    for frame in omega:
        key = f"{omega_path}.{frame}"
        if not _energy_representable(body, np.array(reader.vector(omega[frame], key))):
            reader.fail(key, "so large that the body's energy overflows a float",
                        "give a smaller angular velocity")
    omega_principal = np.zeros(3) if omega_input is None else to_principal @ omega_input
    tensor = body.axes @ np.diag(body.inertia) @ body.axes.T  # in the input body frame
    momentum_input = None if omega_input is None else tensor @ omega_input
    input_rotation = _read_orientation(reader, initial.get("orientation"),
                                       f"{initial_path}.orientation", momentum_input)
    principal_rotation = (input_rotation if np.array_equal(body.axes, np.eye(3))
                          else input_rotation * Rotation.from_matrix(body.axes))
    if "space" in omega:
        omega_space = np.array(reader.vector(omega["space"], f"{omega_path}.space"))
        omega_principal = principal_rotation.inv().apply(omega_space)

    loads_path = f"{path}.loads"
    loads_spec = reader.mapping(spec.get("loads"), loads_path,
                                ("force_space", "force_body", "moment_space", "moment_body",
                                 "gravity"))
    loads_values = {key: reader.vector(value, f"{loads_path}.{key}")
                    for key, value in loads_spec.items()}
    for key in ("force_body", "moment_body"):
        if key in loads_values:
            loads_values[key] = tuple(to_principal @ np.array(loads_values[key]))
    names, offsets = _read_nodes(reader, spec.get("nodes"), f"{path}.nodes")
    duration = reader.number(spec.get("duration", 1.0), f"{path}.duration", positive=True)
    return Scene(
        body=body,
        quaternion=tuple(principal_rotation.as_quat()),
        omega_body=tuple(float(v) for v in omega_principal),
        position=reader.vector(initial.get("position", [0, 0, 0]), f"{initial_path}.position"),
        velocity=reader.vector(initial.get("velocity", [0, 0, 0]), f"{initial_path}.velocity"),
        nodes=offsets @ to_principal.T,
        node_names=names,
        loads=Loads(**loads_values),
        duration=duration,
    )
