"""Bullet's two kinds of free body as rbstudy schemes: a peer engine on the same scenes.

`bullet_multibody` and `bullet_rigidbody` step a scene's body with Bullet itself, through its
Python bindings (the `pybullet` package: rbstudy's extra ``engines``). They are vectorised
schemes (`rbstudy.numerics.batch_driver`): rbstudy's driver samples, judges and times them as
it does its own. One file for the two, because they differ only in the kind of body pybullet
builds, which is the one choice of rotation integrator its Python API offers:

- ``bullet_multibody``: ``createMultiBody`` as pybullet does by default (and ``loadURDF``),
  a Featherstone ``btMultiBody`` with a floating base. Its step computes the accelerations
  with the gyroscopic term ``w x (I w)`` at the old velocity (explicit), updates the
  velocities, then turns the base by the exponential of the new angular velocity.
- ``bullet_rigidbody``: ``useMaximalCoordinates=1``, a ``btRigidBody`` in Bullet's
  discrete world. Since Bullet 2.83 its flags hold ``BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY``:
  one Newton step of backward Euler on Euler's equations in the body frame, then the same
  exponential turn with the new velocity.

What pybullet does not expose (pybullet 3.2.7, checked in its sources): the gyroscopic flags
of a rigid body (explicit, implicit in the world, implicit in the body, none) and the
multibody's ``setUseGyroTerm``; neither ``changeDynamics`` nor ``setPhysicsEngineParameter``
takes them. Nor Bullet's bound on the turn of one step, ``ANGULAR_MOTION_THRESHOLD`` = pi/4
(``btTransformUtil.h``): where ``|w| dt`` passes it, the exponential map lowers the rate in
the half-angle's sine but not in the axis's scale, so that a step turns by
``2 atan(|w| dt tan(pi/8) / (pi/4))`` (0.971 rad for 1 rad, 1.62 for 2), a loss the
archive's ``max_step_angle`` shows (tests/test_bullet.py). What is set, so that the body is
free: linear and angular damping 0 (a multibody's default is 0.04), no sleeping, the
multibody's bound on its coordinates' speed (100 by default) raised past any study's, no
geometry and no collision group (no contact), and Bullet's gravity off.

The scene as Bullet sees it: one body per scene in one world per thread (a ``DIRECT``
connection: no server, no window), its frame at the centre of mass and along the principal
axes, with the scene's mass and principal inertias (``localInertiaDiagonal``). Bullet holds
each body's rotation through its run, as it would for a user's:

1. at the start of a batch (the scheme's init) its bodies are given their initial
   orientations and angular velocities (conventions below); their ids are the bodies' carry;
2. each step, the moment of the loads at its start (`batch_loads`: every load a scene can
   carry) is applied in the world frame and held over the step (Bullet clears it after);
   ``stepSimulation`` takes one step of ``fixedTimeStep`` = dt (no sub-steps) of every
   body of the world at once, and the rotations are read back. A body that stops is
   removed from the world.

The centre of mass is moved by the adapter, with Bullet's own rule for both kinds of body
(the velocity by the force over the step, then the position by the new velocity), while
Bullet's bodies stay parked, each at its own point: Bullet's broadphase, which pybullet
cannot switch off, tests every pair of bodies whose boxes meet every step, and the bodies of
a study mostly share one place (a thousand bodies at one point made each step far dearer). A free body's
rotation does not depend on where it is, and the force is applied at the centre of mass.

Conventions (tests/test_engines.py checks them on a body at rest and on constant spins):
- ``getBasePositionAndOrientation``: the position of the base frame, then the unit
  quaternion *scalar last* (x, y, z, w), mapping body to world, as rbstudy's.
- ``getBaseVelocity``: the linear velocity, then the angular velocity, *both in the world
  frame*; rbstudy's ``omega_body`` is in the body frame (`rbstudy.engines._frames`).

The time measured for a batch is the CPU time of all of the above, Python included, in the
calling thread: pybullet answers each call in that thread (docs/engines.md).
"""

import contextlib
import importlib.metadata
import os
import sys
import threading

import numpy as np

from rbstudy.engines._frames import to_body, to_world
from rbstudy.numerics import state as S
from rbstudy.numerics.batch_driver import batch_loads, make_batch_entry
from rbstudy.numerics.state import OK
from rbstudy.schemes._plugins import SchemeUnavailable
from rbstudy.schemes._registry import Scheme, Style

__all__ = ["MULTIBODY", "RIGIDBODY"]

_INSTALL = 'pip install "pybullet>=3.2.7" (rbstudy\'s extra "bullet")'


@contextlib.contextmanager
def _quiet_stderr():
    """The process's standard error silenced at the descriptor: pybullet's C code prints its
    build time there when imported, among rbstudy's own messages."""
    sys.stderr.flush()
    saved = os.dup(2)
    silent = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(silent, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(silent)


try:
    with _quiet_stderr():
        import pybullet
except ImportError:
    raise SchemeUnavailable("needs the pybullet package", _INSTALL) from None

VERSION = importlib.metadata.version("pybullet")
# Past any study's speed: a multibody clamps every coordinate's velocity to 100 by default.
_UNBOUNDED_SPEED = 1e300
# The step that brings a rigid body's inertia in the world up to date (`_World.start`):
# Bullet skips a step shorter than its epsilon (2.2e-16 s), and turns the body by |w| times
# this, which the state written again afterwards undoes.
_PRIMING_STEP = 1e-12
# Where the bodies are parked in Bullet's world, each at its own point of a cubic lattice of
# this spacing (m) and this many points a side: Bullet's broadphase, which pybullet cannot
# switch off, tests every pair of bodies whose boxes meet, every step, so bodies at one point
# cost O(n^2) a step, where bodies apart cost a little each.
_SPACING, _SIDE = 10.0, 64
# Per thread: one DIRECT connection and its world. dask may step batches in several
# threads; pybullet answers each connection's calls in the caller's thread.
_LOCAL = threading.local()
# Where a body's Bullet id is kept in its work row.
_ID = 0


class _World:
    """One thread's Bullet world, holding the bodies of the batch it runs (a body per scene,
    all of one kind: ``maximal``, a btRigidBody, else a btMultiBody) through their run.
    Bodies are kept from batch to batch (making one is dear next to stepping it), each at its
    own point."""

    def __init__(self):
        self.client = pybullet.connect(pybullet.DIRECT)
        pybullet.setGravity(0.0, 0.0, 0.0, physicsClientId=self.client)
        self.maximal, self.bodies, self.made = None, [], 0

    def __del__(self):  # the thread has ended
        with contextlib.suppress(Exception):
            pybullet.disconnect(self.client)

    def start(self, maximal, y, p, h):
        """Bodies in the orientations and angular velocities of ``y`` (n, N_STATE) with the
        masses and inertias of ``p`` (n, W), in place of the last batch's: their ids (n,).

        pybullet sets a rigid body's orientation and inertias without updating its inverse
        inertia in the world, which Bullet uses for the applied moments of the next step and
        updates only when it moves the body: a step of `_PRIMING_STEP` brings it up to date,
        and the states are written again."""
        if maximal != self.maximal:
            self._keep_first(0)
            self.maximal = maximal
        self._keep_first(len(y))
        while len(self.bodies) < len(y):
            self.bodies.append(self._new(maximal))
        for body, row in zip(self.bodies, p, strict=True):
            pybullet.changeDynamics(
                body,
                -1,
                mass=float(row[S.MASS]),
                localInertiaDiagonal=row[S.INERTIA : S.INERTIA + 3].tolist(),
                physicsClientId=self.client,
            )
        self._write(y)
        self._step(_PRIMING_STEP)
        self._write(y)
        self._step_length(h)
        return np.array(self.bodies, dtype=float)

    def keep(self, ids):
        """Remove the bodies that are not in ``ids`` (they stopped): Bullet steps them no
        more."""
        if len(ids) < len(self.bodies):
            running = set(ids.astype(int).tolist())
            for body in self.bodies:
                if body not in running:
                    pybullet.removeBody(body, physicsClientId=self.client)
            self.bodies = [body for body in self.bodies if body in running]

    def _keep_first(self, n):
        for body in self.bodies[n:]:
            pybullet.removeBody(body, physicsClientId=self.client)
        del self.bodies[n:]

    def _new(self, maximal):
        point = np.unravel_index(self.made % _SIDE**3, (_SIDE,) * 3)
        self.made += 1
        body = pybullet.createMultiBody(
            baseMass=1.0,
            baseCollisionShapeIndex=-1,
            basePosition=[_SPACING * float(i) for i in point],
            useMaximalCoordinates=int(maximal),
            physicsClientId=self.client,
        )
        free = {
            "linearDamping": 0.0,
            "angularDamping": 0.0,
            "activationState": pybullet.ACTIVATION_STATE_DISABLE_SLEEPING,
        }
        if not maximal:
            free["maxJointVelocity"] = _UNBOUNDED_SPEED
        pybullet.setCollisionFilterGroupMask(body, -1, 0, 0, physicsClientId=self.client)
        pybullet.changeDynamics(body, -1, physicsClientId=self.client, **free)
        return body

    def _write(self, y):
        """The orientations and angular velocities of ``y`` into the bodies, at rest where
        they are parked."""
        spin = to_world(y[:, S.QUATERNION : S.QUATERNION + 4], y[:, S.OMEGA : S.OMEGA + 3])
        for k, body in enumerate(self.bodies):
            parked, _ = pybullet.getBasePositionAndOrientation(body, physicsClientId=self.client)
            pybullet.resetBasePositionAndOrientation(
                body, parked, y[k, S.QUATERNION : S.QUATERNION + 4], physicsClientId=self.client
            )
            pybullet.resetBaseVelocity(body, [0.0, 0.0, 0.0], spin[k], physicsClientId=self.client)

    def _step_length(self, h):
        pybullet.setPhysicsEngineParameter(fixedTimeStep=h, numSubSteps=0, physicsClientId=self.client)

    def _step(self, h):
        self._step_length(h)
        pybullet.stepSimulation(physicsClientId=self.client)


def _world():
    if not hasattr(_LOCAL, "world"):
        _LOCAL.world = _World()
    return _LOCAL.world


def _starter(maximal):
    """The vectorised init: the batch's bodies in this thread's world, their ids in
    ``work``."""

    def init(y, p, opt, t, h, work):
        work[:, _ID] = _world().start(maximal, y, p, h)
        return OK

    return init


def step(
    y: np.ndarray, p: np.ndarray, opt: np.ndarray, t: float | None, h: float, work: np.ndarray
) -> tuple[int, int]:
    """One step of every running body: moments applied, one ``stepSimulation``, rotations
    read back, and the centre of mass moved by Bullet's rule (module docstring)."""
    world = _world()
    client = world.client
    ids = work[:, _ID].astype(int).tolist()
    world.keep(work[:, _ID])
    force, moment = batch_loads(y, p, t)
    moment = to_world(y[:, S.QUATERNION : S.QUATERNION + 4], moment)
    for k in np.flatnonzero(moment.any(axis=1)).tolist():
        pybullet.applyExternalTorque(ids[k], -1, moment[k], pybullet.WORLD_FRAME, physicsClientId=client)
    pybullet.stepSimulation(physicsClientId=client)
    spin, orientation = np.empty((len(y), 3)), np.empty((len(y), 4))
    for k, body in enumerate(ids):
        orientation[k] = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)[1]
        spin[k] = pybullet.getBaseVelocity(body, physicsClientId=client)[1]
    # Bullet picks the quaternion's sign afresh from its rotation matrix each step: the one
    # nearer the last keeps the archive's quaternion continuous (the same rotation)
    flip = np.einsum("ij,ij->i", orientation, y[:, S.QUATERNION : S.QUATERNION + 4]) < 0.0
    orientation[flip] *= -1.0
    y[:, S.QUATERNION : S.QUATERNION + 4] = orientation
    y[:, S.OMEGA : S.OMEGA + 3] = to_body(orientation, spin)
    # both kinds of body: the velocity first, then the position with the new velocity
    y[:, S.VELOCITY : S.VELOCITY + 3] += force * (h / p[:, S.MASS, None])
    y[:, S.POSITION : S.POSITION + 3] += y[:, S.VELOCITY : S.VELOCITY + 3] * h
    return OK, 0


def _scheme(name, maximal, summary, step_seconds, style):
    return Scheme(
        name=name,
        summary=f"Bullet {summary}",
        step_seconds=step_seconds,
        order=1,
        implicit=False,  # one Newton step at most: no iterations to count
        # the velocity first, then the turn with the new one; a rigid body's gyroscopic term
        # by one Newton step (a linear solve), a multibody's at the old velocity
        kind="linearly implicit" if maximal else "semi-implicit",
        keeps=(),
        run_bodies_inplace=make_batch_entry(step, _starter(maximal), n_work=1),
        reference="Coumans & Bai, PyBullet, pybullet.org (2016-2021); Featherstone, Rigid "
        "Body Dynamics Algorithms, Springer 2008",
        origin=f"rbstudy's adapter of pybullet {VERSION}",
        code_digest=f"pybullet {VERSION}",  # another Bullet: other parts
        loads_held=True,
        style=style,
    )


MULTIBODY = _scheme(
    "bullet_multibody",
    False,
    "btMultiBody (pybullet's default): gyroscopic term explicit",
    5e-06,
    # MuJoCo's Euler step: another marker and dash than mujoco_euler's, their
    # lines agreeing to 3 digits
    style=Style("teal", "d", "--"),
)
RIGIDBODY = _scheme(
    "bullet_rigidbody",
    True,
    "btRigidBody (maximal coordinates): gyroscopic term implicit",
    7e-06,
    # MuJoCo's implicit step: another marker and dash than mujoco_implicit's
    style=Style("sienna", "h", ":"),
)
