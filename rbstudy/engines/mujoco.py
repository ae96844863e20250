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

1. rbstudy's state rows are written into MuJoCo's (conventions below); each body has a
   model of its own, with its mass and principal inertias and MuJoCo's constants derived
   from them (kept per thread, copied from one template);
2. the loads at the start of the step, `batch_loads` (every load a scene can carry,
   gravity included as a force), go into ``xfrc_applied`` as a force and a moment in the
   world frame at the centre of mass, and are held over the step, as an engine's caller
   applies forces (gravity is switched off in the model: it is in the force);
3. MuJoCo's batch ``rollout`` takes one step of every running body in one call, in this
   thread, and the new states are read back. A state MuJoCo would judge unusable (a value
   past 1e10) stops the body as ``UNSTABLE``, where rbstudy's own driver waits for a
   non-finite value or the drift bound.

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
  to 3-5 digits, ~3x smaller than `rk4`'s on the top. On a loaded body it is of order 1:
  the loads are held over the step (step 2 above), which is how a caller of an engine
  applies them.

The time measured for a batch (`rbstudy.numerics.driver.run_batch`) is the CPU time of the
whole per-step work above, Python included, in the calling thread (the rollout runs there:
threads of its own would escape the clock). A large batch pays little per body-step (Euler
the least, RK4 the most); a batch of one body pays each step the fixed cost of numpy, the
loads and the call (docs/performance.md). Stepping the bodies one ``mj_step`` at a time from
Python cost several times a rollout's body-step: the rollout is what makes MuJoCo's cost its
own.
"""

import copy
import threading

import numpy as np

from rbstudy.engines._frames import to_world
from rbstudy.numerics import state as S
from rbstudy.numerics.batch_driver import batch_loads, make_batch_entry
from rbstudy.numerics.state import OK, UNSTABLE
from rbstudy.schemes._plugins import SchemeUnavailable
from rbstudy.schemes._registry import Scheme, Style

try:
    import mujoco
    from mujoco import rollout
except ImportError:
    raise SchemeUnavailable(
        "needs the mujoco package", 'pip install "mujoco>=4.0" (rbstudy\'s extra "mujoco")'
    ) from None

__all__ = ["EULER", "IMPLICITFAST", "IMPLICIT", "RK4"]

# MuJoCo reports a state it judges unusable (a value past 1e10, or not finite) by printing
# a warning and appending it to MUJOCO_LOG.TXT in the working directory. Studies blow up on
# purpose: the adapter checks the states itself (`_MAX_VALUE`), so the messages are
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
# Per thread: a model per body (its integrator, step, mass and inertias), and the rollout
# that steps them all at once. dask may step batches in several threads.
_LOCAL = threading.local()
# Models kept per thread: a batch's bodies (at most a few hundred) and room for the next.
_MAX_MODELS = 4096
# MuJoCo's bound on a usable value (mjMAXVAL): past it MuJoCo itself judges a state bad.
_MAX_VALUE = 1e10
# A state as rollout takes it (time, qpos (7), qvel (6)), and the applied wrenches (the
# world body's six, then the body's: force and torque in the world frame at its centre).
_STATE, _WIDTH = mujoco.mjtState.mjSTATE_FULLPHYSICS, 14
_WRENCH = mujoco.mjtState.mjSTATE_XFRC_APPLIED


def _template():
    model = mujoco.MjModel.from_xml_string(_MODEL)
    # a blown-up state stays blown up (rbstudy records it), not reset to rest
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    return model, mujoco.MjData(model)


if mujoco.mj_stateSize(_template()[0], _STATE) != _WIDTH:  # another MuJoCo's layout
    raise SchemeUnavailable(
        f"mujoco {mujoco.__version__} lays out a free body's state otherwise than 4.0",
        'pip install "mujoco>=4.0"',
    )


def _thread():
    """This thread's template (a model and its data), its models by body, and its rollout,
    which steps in this thread (dask spreads the batches over threads)."""
    local = _LOCAL.__dict__
    if "template" not in local:
        local.update(template=_template(), models={}, rollout=rollout.Rollout(nthread=0))
    return local


def _model(integrator, h, mass, inertia):
    """This thread's model of a body: copied from the template, given its integrator, step,
    mass and principal inertias, with MuJoCo's derived constants recomputed (``mj_setConst``:
    without it, a body given (1, 2, 3) in place of the template's (1, 1, 1) kept a constant
    orientation error of 0.02 rad under RK4)."""
    local = _thread()
    key = (int(integrator), h, mass, *inertia)
    models = local["models"]
    if key not in models:
        if len(models) >= _MAX_MODELS:
            models.clear()
        template, data = local["template"]
        model = copy.copy(template)  # a deep copy: several times cheaper than compiling it
        model.opt.integrator, model.opt.timestep = integrator, h
        model.body_mass[1], model.body_inertia[1] = mass, inertia
        mujoco.mj_setConst(model, data)
        models[key] = model
    return models[key]


def _stepper(integrator):
    """The vectorised step of MuJoCo's ``integrator`` (module docstring)."""

    def step(y, p, opt, t, h, work):
        n = len(y)
        models = [
            _model(integrator, h, float(row[S.MASS]), tuple(row[S.INERTIA : S.INERTIA + 3])) for row in p
        ]
        force, moment = batch_loads(y, p, t)
        state = np.empty((n, _WIDTH))
        state[:, 0] = 0.0 if t is None else t
        state[:, 1:4] = y[:, S.POSITION : S.POSITION + 3]
        state[:, 4] = y[:, S.QUATERNION + 3]  # scalar first
        state[:, 5:8] = y[:, S.QUATERNION : S.QUATERNION + 3]
        state[:, 8:11] = y[:, S.VELOCITY : S.VELOCITY + 3]
        state[:, 11:14] = y[:, S.OMEGA : S.OMEGA + 3]
        wrench = np.zeros((n, 1, 12))  # the world body's, then the body's: force, torque
        wrench[:, 0, 6:9] = force
        wrench[:, 0, 9:12] = to_world(y[:, S.QUATERNION : S.QUATERNION + 4], moment)
        after = np.empty((n, 1, _WIDTH))
        local = _thread()
        local["rollout"].rollout(
            models,
            [local["template"][1]],
            state,
            wrench,
            control_spec=_WRENCH,
            nstep=1,
            skip_checks=True,
            state=after,
        )
        after = after[:, 0, :]
        y[:, S.POSITION : S.POSITION + 3] = after[:, 1:4]
        y[:, S.QUATERNION + 3] = after[:, 4]
        y[:, S.QUATERNION : S.QUATERNION + 3] = after[:, 5:8]
        y[:, S.VELOCITY : S.VELOCITY + 3] = after[:, 8:11]
        y[:, S.OMEGA : S.OMEGA + 3] = after[:, 11:14]
        # what MuJoCo would have judged unusable (its own counters are per data, not per body)
        bad = ~np.all(np.abs(after[:, 1:]) < _MAX_VALUE, axis=1)
        return np.where(bad, UNSTABLE, OK), 0

    return step


def _scheme(name, integrator, order, kind, summary, step_seconds, style):
    return Scheme(
        name=name,
        summary=f"MuJoCo {summary}",
        step_seconds=step_seconds,
        order=order,
        implicit=False,  # a linear solve at most: no Newton iterations to count
        kind=kind,
        keeps=(),
        run_bodies_inplace=make_batch_entry(_stepper(integrator)),
        reference="Todorov, Erez & Tassa, MuJoCo, IROS 2012; mujoco.readthedocs.io, "
        "Computation: numerical integration",
        origin=f"rbstudy's adapter of mujoco {mujoco.__version__}",
        code_digest=f"mujoco {mujoco.__version__}",  # another MuJoCo: other parts
        loads_held=True,
        style=style,
    )


EULER = _scheme(
    "mujoco_euler",
    mujoco.mjtIntegrator.mjINT_EULER,
    1,
    "semi-implicit",
    "Euler: semi-implicit, velocities then positions",
    2.8e-06,
    style=Style("navy", "<", "-."),
)
IMPLICITFAST = _scheme(
    "mujoco_implicitfast",
    mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    1,
    "linearly implicit",
    "implicitfast: velocity-implicit; on one free body the same as implicit",
    3.0e-06,
    # solid under mujoco_implicit's dashed line: the two coincide on one free
    # body
    style=Style("tab:gray", ">", "-"),
)
IMPLICIT = _scheme(
    "mujoco_implicit",
    mujoco.mjtIntegrator.mjINT_IMPLICIT,
    1,
    "linearly implicit",
    "implicit: the gyroscopic term linearised-implicit",
    3.3e-06,
    # dashed over mujoco_implicitfast's solid line (and bullet_rigidbody's dotted
    # one, which agrees to 3 digits)
    style=Style("darkgoldenrod", "x", "--"),
)
RK4 = _scheme(
    "mujoco_rk4",
    mujoco.mjtIntegrator.mjINT_RK4,
    4,
    "explicit",
    "RK4 on (qpos, qvel), loads held over the step",
    5.7e-06,
    style=Style("magenta", "*", "-."),
)
