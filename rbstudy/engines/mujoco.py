"""MuJoCo's four integrators as rbstudy schemes: a peer engine on the same scenes.

`mujoco_euler`, `mujoco_implicitfast`, `mujoco_implicit` and `mujoco_rk4` step a scene's body
with MuJoCo itself (the `mujoco` package: rbstudy's extra ``engines``). They are
vectorised schemes (`rbstudy.numerics.batch_driver`): rbstudy's driver samples, judges and
times them exactly as it does its own schemes. One file for the four, because they differ
only in MuJoCo's ``opt.integrator``.

The scene as MuJoCo sees it: one body on a free joint, its frame at the centre of mass and
along the principal axes (``<inertial pos="0 0 0" diaginertia=...>``), no geometry, so no
contact and no constraint. Nodes are points of that frame: their positions follow from the
state as they would from MuJoCo's sites (``site_xpos = xpos + R offset``). Every step:

1. rbstudy's state row is written into MuJoCo's (conventions below), the body's mass and
   principal inertias into the model, with MuJoCo's constants derived from them again;
2. the loads at the start of the step, `batch_loads` (every load a scene can carry,
   gravity included as a force), go into ``xfrc_applied`` as a force and a moment in the
   world frame at the centre of mass, and are held over the step, as an engine's caller
   applies forces (gravity is switched off in the model: it is in the force);
3. ``mj_step``, and the new state is read back. A state MuJoCo judges unusable (a value
   past 1e10, or not finite: its warning counters) stops the body as ``UNSTABLE``, where
   rbstudy's own driver waits for a non-finite value or the drift bound.

MuJoCo carries nothing else from step to step here (no contact warm start, no actuator
state), so writing the state each step is the same as letting MuJoCo run on.

Conventions (tests/test_engines.py checks them on a body at rest and on a constant spin):
- MuJoCo's free-joint ``qpos`` is the position of the body frame in the world, then the
  unit quaternion *scalar first* (w, x, y, z), mapping body to world; rbstudy's is scalar
  last (x, y, z, w), with the same map.
- ``qvel`` is the linear velocity in the world frame, then the angular velocity *in the
  body frame*, as rbstudy's ``omega_body``.

How they compare with rbstudy's own schemes (measured on the Abaqus top, an asymmetric
body and a loaded body; tests/test_engines.py):
- ``implicit`` and ``implicitfast`` agree with each other to 2e-15, and with the
  linearised backward Euler of the example plug-in (`examples/semi_implicit`: the
  gyroscopic term implicit in the body frame, one linear solve) to 2e-14, loads included.
  So for one free body MuJoCo 4.0's ``implicitfast`` keeps the derivative of the gyroscopic
  term too (its gyroscopic treatment of a body alone on a free joint; measured with 4.0.0,
  the version the ``engines`` extra asks for). Order 1.
- MuJoCo's Euler is semi-implicit: velocities first, then positions and orientation with
  the new velocities. rbstudy's `euler` turns the frame with the old angular velocity. Both
  are of order 1 and differ by O(h): 1.5e-3 at dt = 0.01 s, 6.8e-4 at 0.005 s.
- MuJoCo's RK4 is of order 4 like rbstudy's `rk4` and differs from it by O(h^4) on a free
  body (4.6e-8, then 2.8e-9); its errors are those of `rkmk4` (RK4 on the rotation group)
  to 3-5 digits, ~3x smaller than `rk4`'s on the top. On a loaded body it is of order 1: the loads are held
  over the step (step 2 above), which is how a caller of an engine applies them.

The time measured for a batch (`rbstudy.numerics.driver.run_batch`) is the CPU time of the
whole per-step work above, Python included: ~15 us a body-step in batches of 100 or more
(~18 us for RK4), of which ``mj_step`` of one free body is ~4 us; a batch of one body pays
~95 us a step, numpy's and the loads' fixed cost (docs/performance.md).
"""

import threading

import numpy as np

from rbstudy.numerics import state as S
from rbstudy.numerics.batch_driver import batch_loads, make_batch_entry
from rbstudy.numerics.state import OK, UNSTABLE
from rbstudy.schemes._plugins import SchemeUnavailable
from rbstudy.schemes._registry import Scheme

try:
    import mujoco
except ImportError:
    raise SchemeUnavailable("needs the mujoco package",
                            'pip install "mujoco>=4.0" (rbstudy\'s extra "engines")') from None

__all__ = ["EULER", "IMPLICITFAST", "IMPLICIT", "RK4"]

# MuJoCo reports a state it judges unusable (a value past 1e10, or not finite) by printing
# a warning and appending it to MUJOCO_LOG.TXT in the working directory. Studies blow up on
# purpose: the adapter reads the warning counters instead (`_BAD`), so the messages are
# silenced, for this process (MuJoCo's handler is process-wide).
mujoco.set_mju_user_warning(lambda message: None)

# One body on a free joint; the body frame at the centre of mass, along the principal axes.
_MODEL = """
<mujoco>
  <option gravity="0 0 0" timestep="0.01"/>
  <worldbody>
    <body><freejoint/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body>
  </worldbody>
</mujoco>
"""
# MuJoCo's reports of a state it judged unusable (a non-finite or huge value).
_BAD = tuple(getattr(mujoco.mjtWarning, name) for name in ("mjWARN_BADQPOS", "mjWARN_BADQVEL",
                                                   "mjWARN_BADQACC"))
# A model and its data per thread and integrator: dask may step batches in several threads.
_LOCAL = threading.local()


def _model_and_data(integrator):
    models = _LOCAL.__dict__.setdefault("models", {})
    if integrator not in models:
        model = mujoco.MjModel.from_xml_string(_MODEL)
        model.opt.integrator = integrator
        # a blown-up state stays blown up (rbstudy records it), not reset to rest
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        models[integrator] = (model, mujoco.MjData(model))
    return models[integrator]


def _set_body(model, data, mass, inertia):
    """Give the model's body ``mass`` and principal ``inertia``, and recompute what MuJoCo
    derives from them (``mj_setConst``, ~1 us): without it, a body given (1, 2, 3) in place
    of the compiled (1, 1, 1) kept a constant orientation error of 0.02 rad under RK4."""
    if model.body_mass[1] != mass or np.any(model.body_inertia[1] != inertia):
        model.body_mass[1] = mass
        model.body_inertia[1] = inertia
        mujoco.mj_setConst(model, data)


def _rotate(q, v):
    """Rotate the vectors ``v`` (n, 3) by the scalar-last unit quaternions ``q`` (n, 4)."""
    u, w = q[:, :3], q[:, 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _stepper(integrator):
    """The vectorised step of MuJoCo's ``integrator`` (module docstring)."""

    def step(y, p, opt, t, h, work):
        model, data = _model_and_data(integrator)
        model.opt.timestep = h
        force, moment = batch_loads(y, p, t)
        quaternion = y[:, S.QUATERNION:S.QUATERNION + 4]
        torque = _rotate(quaternion, moment)  # body frame -> world
        status = np.full(len(y), OK)
        for body in range(len(y)):
            row = y[body]
            _set_body(model, data, p[body, S.MASS], p[body, S.INERTIA:S.INERTIA + 3])
            data.qpos[:3] = row[S.POSITION:S.POSITION + 3]
            data.qpos[3] = row[S.QUATERNION + 3]
            data.qpos[4:] = row[S.QUATERNION:S.QUATERNION + 3]
            data.qvel[:3] = row[S.VELOCITY:S.VELOCITY + 3]
            data.qvel[3:] = row[S.OMEGA:S.OMEGA + 3]
            data.xfrc_applied[1, :3] = force[body]
            data.xfrc_applied[1, 3:] = torque[body]
            data.time = 0.0 if t is None else t
            for kind in _BAD:
                data.warning[kind].number = 0
            mujoco.mj_step(model, data)
            if any(data.warning[kind].number for kind in _BAD):
                status[body] = UNSTABLE
            row[S.POSITION:S.POSITION + 3] = data.qpos[:3]
            row[S.QUATERNION + 3] = data.qpos[3]
            row[S.QUATERNION:S.QUATERNION + 3] = data.qpos[4:]
            row[S.VELOCITY:S.VELOCITY + 3] = data.qvel[:3]
            row[S.OMEGA:S.OMEGA + 3] = data.qvel[3:]
        return status, 0

    return step


def _scheme(name, integrator, order, summary, step_seconds):
    return Scheme(
        name=name,
        summary=f"MuJoCo {summary}",
        step_seconds=step_seconds,
        order=order,
        implicit=False,  # a linear solve at most: no Newton iterations to count
        keeps=(),
        run_bodies_inplace=make_batch_entry(_stepper(integrator)),
        reference="Todorov, Erez & Tassa, MuJoCo, IROS 2012; mujoco.readthedocs.io, "
                  "Computation: numerical integration",
        origin=f"rbstudy's adapter of mujoco {mujoco.__version__}",
        code_digest=f"mujoco {mujoco.__version__}",  # another MuJoCo: other parts
    )


EULER = _scheme("mujoco_euler", mujoco.mjtIntegrator.mjINT_EULER, 1,
                "Euler: semi-implicit, velocities then positions", 1.5e-05)
IMPLICITFAST = _scheme("mujoco_implicitfast", mujoco.mjtIntegrator.mjINT_IMPLICITFAST, 1,
                       "implicitfast: velocity-implicit; on one free body the same as "
                       "implicit", 1.5e-05)
IMPLICIT = _scheme("mujoco_implicit", mujoco.mjtIntegrator.mjINT_IMPLICIT, 1,
                   "implicit: the gyroscopic term linearised-implicit", 1.6e-05)
RK4 = _scheme("mujoco_rk4", mujoco.mjtIntegrator.mjINT_RK4, 4,
              "RK4 on (qpos, qvel), loads held over the step", 1.8e-05)
