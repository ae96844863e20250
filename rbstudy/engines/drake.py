"""Drake's integrators of a free body as rbstudy schemes: a peer engine on the same scenes.

`drake_rk2`, `drake_rk3`, `drake_implicit_euler` and `drake_discrete` step a scene's body with
Drake itself, through its Python bindings (the `drake` package, module ``pydrake``: rbstudy's
extra ``engines``). They are vectorised schemes (`rbstudy.numerics.batch_driver`): rbstudy's
driver samples, judges and times them as it does its own. One file for the four, because they
differ only in how Drake advances the same ``MultibodyPlant``:

- continuous time (``MultibodyPlant(time_step=0)``), through a ``Simulator`` whose integrator
  is chosen by ``ResetIntegratorFromFlags`` and put in fixed-step mode (error control off):
  ``runge_kutta2`` (explicit trapezoid, order 2), ``runge_kutta3`` (order 3), and
  ``implicit_euler`` (order 1): backward Euler on the whole state in the world frame, which
  Drake advances by the two steps of dt/2 it takes for its error estimate, by Newton
  iterations that stop at Drake's default tolerance (1e-4 of a step's turn at |w| dt = 0.5),
  its Jacobian formed afresh at each step (below). Each integrates the plant's ODE for the
  state ``(q, v)``, the quaternion by ``dq/dt = 1/2 q (0, w)``, as any other coordinate: the
  quaternion's norm drifts (Drake issue 14800), and Drake's kinematics normalise it.
- discrete time (``MultibodyPlant(time_step=dt)``), the stepping robotics users run: the
  velocity by the forces at the step's start (the gyroscopic term explicit), then
  ``q += dt N(q) v_next``, again without normalising. Drake 1.51's default discrete model is
  the ``lagged`` approximation, solved by SAP; TAMSI gives the same numbers to round-off on a
  body without contact (tests/test_drake.py), both being the free motion. Order 1.

The scene as Drake sees it: one plant per thread, scheme and step (the discrete plant's step
is built in; the simulator's is set once), holding one free rigid body, its frame at the centre of mass along
the principal axes; the scene's mass and principal inertias are the context's parameters
(``SetSpatialInertiaInBodyFrame``), Drake's gravity is off (the scene's gravity is in the
force, as for every adapter), there is no geometry, so no contact. Each step, for each body:

1. its state is written into the context (conventions below), the quaternion at the norm Drake
   left it (carried in the scheme's work, the archive's being of norm 1);
2. the force and moment at the step's start (`batch_loads`: every load a scene can carry) are
   fixed on the plant's applied spatial force port, in the world frame at the centre of mass,
   and held over the step;
3. the time is set to 0, the simulator initialised, and advanced by one step of dt, which
   keeps each step exactly dt long and no step's numbers dependent on the bodies before it
   (a simulator advanced to ``k dt`` took 1,218 steps for 1,000 at dt = 0.01 s: it caught up
   rounding slivers). For ``implicit_euler`` this forms the Jacobian afresh each step, where a
   simulator left to run reuses it (the two differ within the Newton tolerance: 4e-7 after
   10 s at dt = 0.01 s).

Drake prints nothing when imported nor when stepping; an implicit step whose Newton iterations
fail raises, and stops that body as ``NOT_CONVERGED``.

Conventions (tests/test_engines.py checks them on a body at rest and on constant spins):
- ``GetPositions``: the quaternion *scalar first* (w, x, y, z), mapping body to world once
  normalised, then the position of the body frame in the world; rbstudy's quaternion is
  scalar last and of norm 1.
- ``GetVelocities``: the angular velocity *in the world frame*, then the velocity of the
  centre of mass in the world; rbstudy's ``omega_body`` is in the body frame
  (`rbstudy.engines._frames`).

The time measured for a batch is the CPU time of all of the above, Python included, in the
calling thread: Drake steps there (docs/engines.md).
"""

import importlib.metadata
import math
import threading

import numpy as np

from rbstudy.engines._frames import to_body, to_world
from rbstudy.numerics import state as S
from rbstudy.numerics.batch_driver import batch_loads, make_batch_entry
from rbstudy.numerics.state import NOT_CONVERGED, OK
from rbstudy.schemes._plugins import SchemeUnavailable
from rbstudy.schemes._registry import Scheme, Style

_INSTALL = 'pip install "drake>=1.51" (rbstudy\'s extra "drake")'

try:
    # the package first: its submodules, once imported, would be found even were it hidden
    import pydrake  # noqa: F401
    from pydrake.multibody.math import SpatialForce
    from pydrake.multibody.plant import (
        DiscreteContactApproximation,
        ExternallyAppliedSpatialForce,
        MultibodyPlant,
    )
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia, UnitInertia
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
except ImportError:
    raise SchemeUnavailable("needs the pydrake package", _INSTALL) from None

__all__ = ["RK2", "RK3", "IMPLICIT_EULER", "DISCRETE"]

VERSION = importlib.metadata.version("drake")
# Per thread: a plant, its context and simulator per scheme and step. dask may step batches
# in several threads; a context is not to be shared between them.
_LOCAL = threading.local()
# Plants kept per thread: one per (scheme, dt) of the studies it has run.
_MAX_PLANTS = 64
# Drake 1.51's default discrete model of a plant: SAP's solver of the lagged approximation.
# TAMSI (`kTamsi`) gives the same numbers, to round-off, on a body without contact.
_DISCRETE_MODEL = DiscreteContactApproximation.kLagged
# Where a body's quaternion norm, as Drake holds it, is carried in its work row.
_NORM = 0


class _Plant:
    """One free body in a ``MultibodyPlant``, a context and a simulator that advances it by
    one step of ``h``: with the continuous integrator ``flag`` (`ResetIntegratorFromFlags`),
    or, when ``flag`` is None, by the plant's discrete step of ``h``."""

    def __init__(self, flag, h):
        self.plant = MultibodyPlant(time_step=0.0 if flag else h)
        self.body = self.plant.AddRigidBody(
            "body", SpatialInertia.MakeFromCentralInertia(1.0, [0.0] * 3, RotationalInertia(1.0, 1.0, 1.0))
        )
        self.plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
        if not flag:
            self.plant.set_discrete_contact_approximation(_DISCRETE_MODEL)
        self.plant.Finalize()
        self.context = self.plant.CreateDefaultContext()
        self.simulator = Simulator(self.plant, self.context)
        if flag:
            ResetIntegratorFromFlags(self.simulator, flag, h).set_fixed_step_mode(True)
        self.h, self.inertia, self.load = h, None, None
        self._fix_load([0.0] * 6)

    def step(self, x, inertia, load):
        """One step from the state ``x`` (13,: Drake's positions, then velocities), with the
        body's mass and principal inertias ``inertia`` (4-tuple) and ``load`` (a 6-list: force,
        moment in the world): the state (13,) after it."""
        if inertia != self.inertia:
            mass, *principal = inertia
            # Drake refuses an inertia that breaks the triangle inequality (a numerical stress
            # body, `allow_unphysical`) unless told to skip the check; its equations of motion
            # hold for any positive principal inertias, as rbstudy's own and MuJoCo's do.
            unit = UnitInertia(*(moment / mass for moment in principal))
            self.body.SetSpatialInertiaInBodyFrame(
                self.context, SpatialInertia(mass, [0.0] * 3, unit, skip_validity_check=True)
            )
            self.inertia = inertia
        if load != self.load:
            self._fix_load(load)
        self.plant.SetPositionsAndVelocities(self.context, x)
        self.context.SetTime(0.0)
        self.simulator.Initialize()
        self.simulator.AdvanceTo(self.h)
        return self.plant.GetPositionsAndVelocities(self.context)

    def _fix_load(self, load):
        applied = ExternallyAppliedSpatialForce()
        applied.body_index = self.body.index()
        applied.p_BoBq_B = np.zeros(3)
        applied.F_Bq_W = SpatialForce(tau=load[3:], f=load[:3])
        self.plant.get_applied_spatial_force_input_port().FixValue(self.context, [applied])
        self.load = load


def _plant(flag, h):
    """This thread's plant for the integrator ``flag`` (None: discrete) and step ``h``."""
    plants = _LOCAL.__dict__.setdefault("plants", {})
    if (flag, h) not in plants:
        if len(plants) >= _MAX_PLANTS:
            plants.clear()
        plants[(flag, h)] = _Plant(flag, h)
    return plants[(flag, h)]


def _start(y, p, opt, t, h, work):
    """The vectorised init: every body's quaternion of norm 1, as rbstudy's states are."""
    work[:, _NORM] = 1.0
    return OK


def _stepper(flag):
    """The vectorised step of Drake's integrator ``flag`` (None: the discrete plant)."""

    def step(y, p, opt, t, h, work):
        plant = _plant(flag, h)
        force, moment = batch_loads(y, p, t)
        unit = y[:, S.QUATERNION : S.QUATERNION + 4]
        # Drake's states (n, 13): the quaternion scalar first at Drake's norm, the position;
        # the angular velocity in the world, the velocity
        x = np.concatenate(
            [
                unit[:, 3:] * work[:, _NORM, None],
                unit[:, :3] * work[:, _NORM, None],
                y[:, S.POSITION : S.POSITION + 3],
                to_world(unit, y[:, S.OMEGA : S.OMEGA + 3]),
                y[:, S.VELOCITY : S.VELOCITY + 3],
            ],
            axis=1,
        )
        loads = np.concatenate([force, to_world(unit, moment)], axis=1).tolist()
        inertias = [tuple(row) for row in p[:, S.MASS : S.INERTIA + 3].tolist()]
        status = np.full(len(y), OK)
        for k in range(len(y)):
            try:
                x[k] = plant.step(x[k], inertias[k], loads[k])
            except RuntimeError:  # Drake's implicit step failed to converge: the body as it was
                status[k] = NOT_CONVERGED
        # inf, not an overflow warning, past 1e154
        work[:, _NORM] = [math.hypot(*row) for row in x[:, :4].tolist()]
        unit = np.concatenate([x[:, 1:4], x[:, :1]], axis=1) / work[:, _NORM, None]
        y[:, S.QUATERNION : S.QUATERNION + 4] = unit
        y[:, S.POSITION : S.POSITION + 3] = x[:, 4:7]
        y[:, S.OMEGA : S.OMEGA + 3] = to_body(unit, x[:, 7:10])
        y[:, S.VELOCITY : S.VELOCITY + 3] = x[:, 10:13]
        return status, 0

    return step


def _scheme(name, flag, order, summary, step_seconds, style):
    return Scheme(
        name=name,
        summary=f"Drake {summary}",
        step_seconds=step_seconds,
        order=order,
        # Newton iterations Drake's own: pydrake does not expose the implicit integrator's
        # counters, so the archive's `iterations` stays 0
        implicit=flag == "implicit_euler",
        # the discrete plant: the velocity by the forces at the step's start, then q by it
        kind="semi-implicit" if flag is None else None,
        keeps=(),
        run_bodies_inplace=make_batch_entry(_stepper(flag), _start, n_work=1),
        reference="Tedrake et al., Drake: model-based design and verification for robotics, "
        "drake.mit.edu (2019-2025); Castro et al., An unconstrained convex "
        "formulation of compliant contact (SAP), IEEE T-RO 2023",
        origin=f"rbstudy's adapter of Drake {VERSION}",
        code_digest=f"drake {VERSION}",  # another Drake: other parts
        loads_held=True,
        style=style,
    )


RK2 = _scheme(
    "drake_rk2",
    "runge_kutta2",
    2,
    "RungeKutta2Integrator, fixed step, on the continuous plant",
    1.5e-05,
    Style("mediumvioletred", "d", "-"),
)
RK3 = _scheme(
    "drake_rk3",
    "runge_kutta3",
    3,
    "RungeKutta3Integrator, fixed step (error control off)",
    1.8e-05,
    Style("olivedrab", "h", "--"),
)
IMPLICIT_EULER = _scheme(
    "drake_implicit_euler",
    "implicit_euler",
    1,
    "ImplicitEulerIntegrator, fixed step (error control off)",
    7.9e-05,
    Style("chocolate", "p", "-."),
)
DISCRETE = _scheme(
    "drake_discrete",
    None,
    1,
    "discrete MultibodyPlant (time_step = dt, SAP): explicit forces",
    1.6e-05,
    Style("steelblue", "1", ":"),
)
