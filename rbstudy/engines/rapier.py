"""Rapier's rigid body as an rbstudy scheme: a game engine's free body in single precision.

`rapier` steps a scene's body with Rapier itself, through its Python bindings (the
`rapier3d` package: rbstudy's extra ``rapier``). It is a vectorised scheme
(`rbstudy.numerics.batch_driver`): rbstudy's driver samples, judges and times it as it does
its own. Rapier computes in float32: where its rounding sets the error is a finding, and
the card shows it (docs/engines.md).

Rapier's step, as its sources give it (rapier 0.3x, ``src/dynamics/rigid_body.rs``
``gyroscopic_corrected_angvel`` and ``rigid_body_components.rs`` ``integrate_linearized``),
is ``num_solver_iterations`` substeps (4 by default, kept: as its users run it) of length
``dt/4``, each:

    m' = m + d m x w, scaled back to |m|     (Jolt's gyroscopic step, body axes; `jolt`)
    w+ = I^-1 m' + d I^-1 M                  (the torque's impulse, held over the step)
    q+ = normalise((d w+_world / 2, 1) q)    (the rotation linearised: the Cayley map of d w+)

so it is rbstudy's `jolt` with the frame turned by the Cayley map instead of the exponential,
four substeps a step, in float32 (a test shows the agreement to float32's precision). Option
``gyroscopic`` (1 by default, as the bindings build a body) switches Rapier's gyroscopic
forces; with 0 the spin is held in the world between torques, which is right only for a body
whose inertia is a sphere's.

The scene as Rapier sees it: one dynamic body per scene in one world per thread, no collider
(no contact, no broadphase pairs), its mass and principal inertias given as additional mass
properties, no damping, no sleeping, no gravity (the loads carry it), held at the origin. Rapier
holds each body's rotation through its run, as it would for a user's:

1. at the start of a batch (the scheme's init) its bodies are made with their initial
   orientations and angular velocities (in the world, as Rapier reads them); their places in
   the thread's list are the bodies' carry;
2. each step, the moment of the loads at its start (`batch_loads`) is set as the body's
   torque in the world frame and held over the step; ``PhysicsWorld.step`` takes one step of
   ``integration_parameters.dt`` = dt (rounded to float32) of every body at once, and the
   rotations are read back. A body that stops is removed from the world.

The centre of mass is moved by the adapter, with Rapier's own rule (the velocity by the force
over the step, then the position by the new velocity), in float64: the rotation is what is
studied, and a float32 position would hide it behind its own rounding far from the origin.

Conventions (tests/test_engines.py checks them on a body at rest and on constant spins):
``RigidBody.rotation`` is a unit quaternion ``(w, x, y, z)`` mapping body to world, read as
rbstudy's scalar-last (x, y, z, w); ``RigidBody.angvel`` is in the world frame, rbstudy's
``omega_body`` in the body frame (`rbstudy.engines._frames`).

The time measured for a batch is the CPU time of all of the above, Python included, in the
calling thread (docs/engines.md).
"""

import importlib.metadata
import threading

import numpy as np

from rbstudy.engines._frames import to_body, to_world
from rbstudy.numerics import state as S
from rbstudy.numerics.batch_driver import batch_loads, make_batch_entry
from rbstudy.numerics.state import OK
from rbstudy.schemes._plugins import SchemeUnavailable
from rbstudy.schemes._registry import Option, Scheme, Style, flag_parser, option_slots

__all__ = ["RAPIER"]

_INSTALL = 'pip install "rapier3d>=0.36" (rbstudy\'s extra "rapier")'

try:
    import rapier3d
except ImportError:
    raise SchemeUnavailable("needs the rapier3d package", _INSTALL) from None

VERSION = importlib.metadata.version("rapier3d")
# Per thread: one world. dask may step batches in several threads; a world may be used from
# any thread, but not by two at once.
_LOCAL = threading.local()
# Where a body's place in its thread's list is kept in its work row.
_ID = 0

GYROSCOPIC = Option(
    name="gyroscopic",
    default=1,
    description="1: Rapier's gyroscopic forces on (as its bindings build a body); 0: off, the "
    "spin held in the world between torques",
    parse=flag_parser("step Rapier's gyroscopic forces"),
    long_name="Rapier's gyroscopic forces",
    units="1",
)
_OPTIONS = (GYROSCOPIC,)
_SLOTS = option_slots(_OPTIONS)


def _vector(v):
    return rapier3d.Vec3(float(v[0]), float(v[1]), float(v[2]))


class _World:
    """One thread's Rapier world, holding the bodies of the batch it runs (a body per scene)
    through their run."""

    def __init__(self):
        self.world = rapier3d.PhysicsWorld()
        self.handles = []

    def start(self, y, p, gyroscopic, h):
        """Bodies in the orientations and angular velocities of ``y`` (n, N_STATE) with the
        masses and inertias of ``p`` (n, W), Rapier's gyroscopic forces as ``gyroscopic``
        (n,) says, in place of the last batch's: their places (n,)."""
        self.keep(np.zeros(0))
        self.world.integration_parameters.dt = h
        spin = to_world(y[:, S.QUATERNION : S.QUATERNION + 4], y[:, S.OMEGA : S.OMEGA + 3])
        for row, params, gyro, w in zip(y, p, gyroscopic, spin, strict=True):
            mass = rapier3d.MassProperties(
                rapier3d.Vec3(0.0, 0.0, 0.0),
                float(params[S.MASS]),
                _vector(params[S.INERTIA : S.INERTIA + 3]),
                rapier3d.Quaternion.identity(),
            )
            builder = (
                rapier3d.RigidBody.dynamic()
                .additional_mass_properties(mass)
                .gyroscopic_forces(bool(gyro))
                .angular_damping(0.0)
                .linear_damping(0.0)
                .can_sleep(False)
                .angvel(_vector(w))
            )
            handle = self.world.add_body(builder)
            x, y_, z, s = row[S.QUATERNION : S.QUATERNION + 4]
            self.world.rigid_bodies[handle].rotation = rapier3d.Rotation3.from_quaternion(s, x, y_, z)
            self.handles.append(handle)
        return np.arange(len(y), dtype=float)

    def keep(self, places):
        """Remove the bodies whose places are not in ``places`` (they stopped): Rapier steps
        them no more."""
        running = set(places.astype(int).tolist())
        for k, handle in enumerate(self.handles):
            if handle is not None and k not in running:
                self.world.remove_body(handle)
                self.handles[k] = None
        if not running:
            self.handles = []

    def step(self, places, torque):
        """One step of every running body under the world-frame ``torque`` (n, 3) at
        ``places`` (n,): their orientations (n, 4, scalar last) and world spins (n, 3)."""
        bodies = self.world.rigid_bodies
        for k, place in enumerate(places):
            body = bodies[self.handles[place]]
            body.reset_torques()
            if torque[k].any():
                body.add_torque(_vector(torque[k]))
        self.world.step()
        orientation, spin = np.empty((len(places), 4)), np.empty((len(places), 3))
        for k, place in enumerate(places):
            body = bodies[self.handles[place]]
            q, w = body.rotation, body.angvel
            orientation[k] = (q.i, q.j, q.k, q.w)
            spin[k] = (w.x, w.y, w.z)
        return orientation, spin


def _world():
    if not hasattr(_LOCAL, "world"):
        _LOCAL.world = _World()
    return _LOCAL.world


def init(y: np.ndarray, p: np.ndarray, opt: np.ndarray, t: float | None, h: float, work: np.ndarray) -> int:
    """The vectorised init: the batch's bodies in this thread's world, their places in
    ``work``."""
    work[:, _ID] = _world().start(y, p, opt[:, _SLOTS["gyroscopic"]] != 0.0, h)
    return OK


def step(
    y: np.ndarray, p: np.ndarray, opt: np.ndarray, t: float | None, h: float, work: np.ndarray
) -> tuple[int, int]:
    """One step of every running body: torques set, one ``PhysicsWorld.step``, rotations
    read back, and the centre of mass moved by Rapier's rule (module docstring)."""
    world = _world()
    world.keep(work[:, _ID])
    force, moment = batch_loads(y, p, t)
    quaternion = y[:, S.QUATERNION : S.QUATERNION + 4]
    orientation, spin = world.step(work[:, _ID].astype(int).tolist(), to_world(quaternion, moment))
    # the quaternion of the two signs nearer the last keeps the archive's quaternion continuous
    flip = np.einsum("ij,ij->i", orientation, quaternion) < 0.0
    orientation[flip] *= -1.0
    y[:, S.QUATERNION : S.QUATERNION + 4] = orientation
    y[:, S.OMEGA : S.OMEGA + 3] = to_body(orientation, spin)
    y[:, S.VELOCITY : S.VELOCITY + 3] += force * (h / p[:, S.MASS, None])
    y[:, S.POSITION : S.POSITION + 3] += y[:, S.VELOCITY : S.VELOCITY + 3] * h
    return OK, 0


RAPIER = Scheme(
    name="rapier",
    summary="Rapier (float32): 4 substeps of Jolt's gyroscopic step with a Cayley turn",
    step_seconds=5.9e-06,  # a body-step at B = 1e4 on one core (`rbstudy bench rapier`)
    order=1,
    implicit=False,
    kind="semi-implicit",
    keeps=(),
    run_bodies_inplace=make_batch_entry(step, init, n_work=1),
    reference="Dimforge, Rapier physics engine, rapier.rs (src/dynamics/rigid_body.rs)",
    options=_OPTIONS,
    origin=f"rbstudy's adapter of rapier3d {VERSION}",
    code_digest=f"rapier3d {VERSION}",
    loads_held=True,
    style=Style("peru", "v", "--"),
)
