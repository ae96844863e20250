"""Exudyn's solvers as rbstudy schemes: a peer engine on the same scenes.

`exudyn_genalpha`, `exudyn_rk44` and `exudyn_midpoint` step a scene's body with Exudyn itself
(the `exudyn` package: rbstudy's extra ``engines``), through its solver classes. They are
vectorised schemes (`rbstudy.numerics.batch_driver`): rbstudy's driver samples, judges and
times them as it does its own. The body is an ``ObjectRigidBody`` on one of two nodes, each
the one its solver takes:

- ``exudyn_genalpha``: the implicit generalized-alpha solver (``MainSolverImplicitSecondOrder``,
  ``DynamicSolverType.GeneralizedAlpha``; Arnold & Bruls 2007) on a ``NodeRigidBodyEP``: the
  Euler parameters are the coordinates, their unit norm an algebraic equation (index 3) the
  solver holds with a Lagrange multiplier. Option ``spectral_radius`` is Exudyn's
  ``spectralRadius`` (default 0.9, Exudyn's): 1 is no numerical damping, which Exudyn's
  index-3 constraint does not allow, so it must be below 1. Exudyn's Newton settings are its
  defaults (modified Newton, relative tolerance 1e-8); the iterations are counted.
- ``exudyn_rk44`` and ``exudyn_midpoint``: the explicit solver (``MainSolverExplicit``, ``RK44``
  and ``ExplicitMidpoint``) with its Lie-group integration on a ``NodeRigidBodyRotVecLG``: the
  rotation is updated by the exponential map of the stages' increments (Holzinger & Gerstmayr
  2021), the angular velocity in the body frame is the velocity coordinate. The explicit
  solvers refuse a node with an algebraic equation, so they cannot take the Euler-parameter
  node (``ModelError``: "explicit integrator detected node 0 which contains algebraic
  variables"; tests/test_exudyn.py).

Every scene is represented. Its constant loads are Exudyn's own (``LoadForceVector``,
``LoadTorqueVector``, in space or body axes; a space force at a node as a force at a body
point), which its solvers evaluate at every stage and Newton iterate, so that the schemes
keep their order under loads; loads tabulated in time go in as a force and a moment in the
world frame at the centre of mass, held over the step (Exudyn would call back into Python
at every stage for them). Exudyn writes nothing and prints nothing here: its solution,
sensor and restart files, its console output and its statistics are turned off, and the step
is fixed (no step-size control, no adaptive step reduction after a failed Newton).

Each body is a system of its own (``SystemContainer``) with its own solver, kept from the
scheme's init to the end of its run, so that the generalized-alpha solver carries its
algorithmic accelerations from step to step as in one ``SolveDynamic``, and a body's Newton
iterations do not depend on the bodies beside it. Each step moves the solver's start and
end time one step on and calls ``SolveSteps``: the states agree with one ``SolveDynamic``
over the run to the bit (explicit) and to 2e-10 (the Newton tolerance; generalized alpha).
The coordinates are read back with ``GetODE2Coordinates`` (and ``_t``), displacements from
the node's reference:

- Euler parameters ``(e0, e1, e2, e3)``, scalar *first*, body to world, held at unit norm to
  the Newton tolerance; the angular velocity in the body frame is ``2 conj(e) e_t``.
- the rotation vector of the Lie-group node (not wrapped to pi), and its velocity coordinates,
  which are the angular velocity *in the body frame*.

The time measured for a batch is the CPU time of all of the above, Python included, in the
calling thread (Exudyn is given one thread, its default).
"""

import importlib.metadata
import threading

import numpy as np

from rbstudy.engines._frames import to_world
from rbstudy.errors import SchemeError
from rbstudy.numerics import state as S
from rbstudy.numerics.batch_driver import batch_loads, make_batch_entry
from rbstudy.numerics.loads import END_SLOT, FIRST_SLOT, LOAD_KINDS
from rbstudy.numerics.state import NOT_CONVERGED, OK, UNSTABLE
from rbstudy.schemes._plugins import SchemeUnavailable
from rbstudy.schemes._registry import Option, Scheme, Style, option_slots

__all__ = ["GENALPHA", "RK44", "MIDPOINT"]

_INSTALL = 'pip install "exudyn>=1.13.6" (rbstudy\'s extra "exudyn")'

try:
    import exudyn
    from exudyn import itemInterface as items
except ImportError:
    raise SchemeUnavailable("needs the exudyn package", _INSTALL) from None

VERSION = importlib.metadata.version("exudyn")
# Exudyn's default spectral radius of generalized alpha (GeneralizedAlphaSettings); below 1,
# which its index-3 constraint of the Euler parameters requires (Exudyn's docs).
SPECTRAL_RADIUS = 0.9
# Per thread: the running bodies' systems (dask may step batches in several threads).
_LOCAL = threading.local()
# Where a body's number in this thread's list of systems is kept in its work row.
_ID = 0


def _parse_spectral_radius(value):
    expected = (
        "expected a number in [0, 1): Exudyn's index-3 constraint of the Euler parameters needs some damping"
    )
    try:
        rho = float(value)
    except (TypeError, ValueError):
        raise ValueError(expected) from None
    if not 0.0 <= rho < 1.0:
        raise ValueError(expected)
    return (rho,)


SPECTRAL_RADIUS_OPTION = Option(
    name="spectral_radius",
    default=SPECTRAL_RADIUS,
    description="Exudyn's spectralRadius of generalized alpha, in [0, 1); lower damps more",
    parse=_parse_spectral_radius,
    long_name="generalized-alpha spectral radius at infinity",
    units="1",
)


# where the generalized-alpha schemes read the option (the registry's layout, `option_slots`);
# the others, which have no options, read the 0 of an empty row there and never use it
_SPECTRAL_RADIUS = option_slots((SPECTRAL_RADIUS_OPTION,))["spectral_radius"]


def _settings(solver_type, h, spectral_radius):
    """Exudyn's simulation settings for fixed steps of ``h`` with nothing written or printed."""
    settings = exudyn.SimulationSettings()
    solution = settings.solution
    solution.file.write = False
    solution.sensors.active = False
    solution.restart.write = False
    settings.show.statistics = False
    settings.show.computationTime = False
    settings.show.globalTimers = False
    integration = settings.timeIntegration
    integration.verboseMode = 0
    integration.verboseModeFile = 0
    integration.solverType = solver_type
    integration.adaptiveStep = False  # a failed Newton is a failed step, not a shorter one
    integration.automaticStepSize = False
    integration.explicit.useLieGroupIntegration = True
    integration.generalizedAlpha.spectralRadius = spectral_radius
    # a step of (endTime - startTime) / numberOfSteps = h; `_Body.step` moves both ends on
    integration.numberOfSteps = 1
    integration.endTime = h
    return settings


def _quaternion_product(a, b):
    """``a b`` (n, 4) of scalar-first quaternions ``a`` and ``b`` (n, 4)."""
    aw, av, bw, bv = a[:, :1], a[:, 1:], b[:, :1], b[:, 1:]
    return np.hstack([aw * bw - np.sum(av * bv, axis=1, keepdims=True), aw * bv + bw * av + np.cross(av, bv)])


def _rotation_vector(q):
    """The rotation vectors (n, 3) of the scalar-last unit quaternions ``q`` (n, 4), of angle
    at most pi."""
    q = np.where(q[:, 3:] < 0.0, -q, q)
    sine = np.linalg.norm(q[:, :3], axis=1)
    angle = 2.0 * np.arctan2(sine, q[:, 3])
    scale = np.where(sine > 0.0, angle / np.where(sine > 0.0, sine, 1.0), 2.0)
    return q[:, :3] * scale[:, None]


def _quaternion_of(rotation_vector):
    """The scalar-last unit quaternions (n, 4) of the ``rotation_vector`` rows (n, 3)."""
    angle = np.linalg.norm(rotation_vector, axis=1)
    half = 0.5 * angle
    # sin(a/2)/a -> 1/2 as a -> 0; np.sinc(x) = sin(pi x)/(pi x)
    scale = 0.5 * np.sinc(half / np.pi)
    return np.hstack([rotation_vector * scale[:, None], np.cos(half)[:, None]])


class _Kind:
    """How one of Exudyn's solvers sees a body: the solver, its node, and the node's
    coordinates to and from rbstudy's state rows."""

    def __init__(self, solver_type, euler_parameters):
        self.solver_type = solver_type
        self.euler_parameters = euler_parameters
        self.implicit = solver_type == exudyn.DynamicSolverType.GeneralizedAlpha

    def node(self, y):
        """The nodes (n) of the states ``y`` (n, N_STATE): its reference coordinates (the
        initial state) and initial velocities."""
        q = y[:, S.QUATERNION : S.QUATERNION + 4]
        w = y[:, S.OMEGA : S.OMEGA + 3]
        if self.euler_parameters:
            e = np.hstack([q[:, 3:], q[:, :3]])
            e_t = 0.5 * _quaternion_product(e, np.hstack([np.zeros((len(y), 1)), w]))
            rotation, spin, node = e, e_t, items.NodeRigidBodyEP
        else:
            rotation, spin, node = _rotation_vector(q), w, items.NodeRigidBodyRotVecLG
        return [
            node(
                referenceCoordinates=[*y[k, S.POSITION : S.POSITION + 3], *rotation[k]],
                initialVelocities=[*y[k, S.VELOCITY : S.VELOCITY + 3], *spin[k]],
            )
            for k in range(len(y))
        ]

    def read(self, y, reference, coordinates, velocities):
        """The state rows ``y`` (n, N_STATE) in place from the nodes' ``reference``,
        ``coordinates`` and ``velocities`` (n, 6 or 7)."""
        current = reference + coordinates
        y[:, S.POSITION : S.POSITION + 3] = current[:, :3]
        y[:, S.VELOCITY : S.VELOCITY + 3] = velocities[:, :3]
        if self.euler_parameters:
            e = current[:, 3:]
            q = np.hstack([e[:, 1:], e[:, :1]])
            conjugate = e * [1.0, -1.0, -1.0, -1.0]
            y[:, S.OMEGA : S.OMEGA + 3] = 2.0 * _quaternion_product(conjugate, velocities[:, 3:])[:, 1:]
        else:
            q = _quaternion_of(current[:, 3:])
            y[:, S.OMEGA : S.OMEGA + 3] = velocities[:, 3:]
        # the sign nearer the last step's keeps the archive's quaternion continuous
        flip = np.einsum("ij,ij->i", q, y[:, S.QUATERNION : S.QUATERNION + 4]) < 0.0
        q[flip] *= -1.0
        y[:, S.QUATERNION : S.QUATERNION + 4] = q


class _Body:
    """One body in a system of its own, with its solver, started at its initial state: the
    node ``node`` of ``kind``, the mass, inertias and loads of the parameter row ``p``."""

    def __init__(self, kind, node, p, h, spectral_radius):
        self.container = exudyn.SystemContainer()
        mbs = self.mbs = self.container.AddSystem()
        number = mbs.AddNode(node)
        body = mbs.AddObject(
            items.ObjectRigidBody(
                mass=float(p[S.MASS]),
                inertia=[*p[S.INERTIA : S.INERTIA + 3].tolist(), 0.0, 0.0, 0.0],
                nodeNumber=number,
            )
        )
        centre = mbs.AddMarker(items.MarkerNodeRigid(nodeNumber=number))
        _add_constant_loads(mbs, body, centre, p)
        # the loads tabulated in time, held over each step (`hold`)
        self.force = mbs.AddLoad(
            items.LoadForceVector(markerNumber=centre, bodyFixed=False, loadVector=[0.0, 0.0, 0.0])
        )
        self.moment = mbs.AddLoad(
            items.LoadTorqueVector(markerNumber=centre, bodyFixed=False, loadVector=[0.0, 0.0, 0.0])
        )
        mbs.Assemble()
        self.reference = np.array(node.referenceCoordinates)
        self.settings = _settings(kind.solver_type, h, spectral_radius)
        self.solver = exudyn.MainSolverImplicitSecondOrder() if kind.implicit else exudyn.MainSolverExplicit()
        self.solver.InitializeSolver(mbs, self.settings)

    def hold(self, force, moment):
        """The world ``force`` and ``moment`` (3,) at the centre of mass over the next step."""
        self.mbs.SetLoadParameter(self.force, "loadVector", force.tolist())
        self.mbs.SetLoadParameter(self.moment, "loadVector", moment.tolist())

    def step(self, h):
        """One step of ``h``: whether Exudyn's solver took it (a Newton that converged), and
        its Newton iterations."""
        iteration = self.solver.it
        before = iteration.newtonStepsCount
        # both ends move: with the start left behind, a call takes a step as long as the run
        iteration.startTime = iteration.currentTime
        iteration.endTime = iteration.currentTime + h
        done = self.solver.SolveSteps(self.mbs, self.settings)
        return done, iteration.newtonStepsCount - before


# The kinds of load (`rbstudy.numerics.loads`) that are Exudyn's own (`_add_constant_loads`);
# a scene with another kind is refused.
_NATIVE_LOADS = ("force_space", "force_body", "moment_space", "moment_body", "gravity", "lever")


def _add_constant_loads(mbs, body, centre, p):
    """The constant loads of the parameter row ``p`` as Exudyn's own loads on ``body`` (whose
    node's marker is ``centre``), which its solvers evaluate at every stage and Newton
    iterate, as rbstudy's schemes do: forces and moments in space (``bodyFixed=False``) or
    in body axes (``True``), the weight, and the space forces at body-fixed points. Those
    are rows ``k_b`` of `S.LEVER` whose moment is ``sum_b (R e_b) x k_b``: a force ``k_b`` at
    the body point ``e_b`` each, less their sum at the centre of mass (the node forces' sum
    is in the space force already)."""
    lever = p[S.LEVER : S.LEVER + 9].reshape(3, 3)
    space_force = (
        p[S.FORCE_SPACE : S.FORCE_SPACE + 3] + p[S.MASS] * p[S.GRAVITY : S.GRAVITY + 3] - lever.sum(axis=0)
    )
    loads = [
        (items.LoadForceVector, centre, space_force, False),
        (items.LoadForceVector, centre, p[S.FORCE_BODY : S.FORCE_BODY + 3], True),
        (items.LoadTorqueVector, centre, p[S.MOMENT_SPACE : S.MOMENT_SPACE + 3], False),
        (items.LoadTorqueVector, centre, p[S.MOMENT_BODY : S.MOMENT_BODY + 3], True),
    ]
    for axis, force in enumerate(lever):
        if force.any():
            point = mbs.AddMarker(
                items.MarkerBodyPosition(bodyNumber=body, localPosition=np.eye(3)[axis].tolist())
            )
            loads.append((items.LoadForceVector, point, force, False))
    for load, marker, vector, body_fixed in loads:
        if vector.any():
            mbs.AddLoad(load(markerNumber=marker, loadVector=vector.tolist(), bodyFixed=body_fixed))


def _bodies():
    if not hasattr(_LOCAL, "bodies"):
        _LOCAL.bodies = []
    return _LOCAL.bodies


def _refuse_foreign_loads(name, p):
    """Refuse parameter rows ``p`` (B, W) that carry a kind of load Exudyn does not take
    (`_NATIVE_LOADS`), in one line naming it."""
    for load in LOAD_KINDS:
        if load.name not in _NATIVE_LOADS and np.any(p[:, load.offset : load.offset + load.width]):
            raise SchemeError(
                f"scheme {name} cannot take scene.loads.{load.name}",
                "Exudyn has no such load: leave the scheme out",
            )


def _starter(kind, name):
    """The vectorised init of the scheme ``name``: a system per body of the batch, in place
    of this thread's last batch's; their numbers in ``work``."""

    def init(y, p, opt, t, h, work):
        _refuse_foreign_loads(name, p)
        bodies = _bodies()
        bodies.clear()
        for k, node in enumerate(kind.node(y)):
            bodies.append(_Body(kind, node, p[k], h, float(opt[k, _SPECTRAL_RADIUS])))
        work[:, _ID] = np.arange(len(y))
        return OK

    return init


def _hold_tabulated_loads(bodies, y, p, t):
    """The loads tabulated in time of the bodies that have them, at the step's start ``t``,
    held over the step (`_Body.hold`): Exudyn would call back into Python at every stage."""
    timed = np.flatnonzero(p[:, S.KNOTS] > 0)
    if timed.size:
        tabulated_only = p[timed].copy()
        tabulated_only[:, FIRST_SLOT:END_SLOT] = 0.0  # the constant loads are Exudyn's
        force, moment = batch_loads(y[timed], tabulated_only, t)
        moment = to_world(y[timed, S.QUATERNION : S.QUATERNION + 4], moment)
        for j, k in enumerate(timed.tolist()):
            bodies[k].hold(force[j], moment[j])


def _stepper(kind):
    """The vectorised step of ``kind`` (module docstring)."""

    def step(y, p, opt, t, h, work):
        bodies = [_bodies()[k] for k in work[:, _ID].astype(int).tolist()]
        _hold_tabulated_loads(bodies, y, p, t)
        status = np.full(len(y), OK)
        iterations = np.zeros(len(y), dtype=np.int64)
        for k, body in enumerate(bodies):
            try:
                done, iterations[k] = body.step(h)
            except exudyn.SolverError:  # noqa: PERF203 (a body's failure is its own)
                done = False
            if not done:
                status[k] = NOT_CONVERGED if kind.implicit else UNSTABLE
        kind.read(
            y,
            np.array([body.reference for body in bodies]),
            np.array([body.mbs.systemData.GetODE2Coordinates() for body in bodies]),
            np.array([body.mbs.systemData.GetODE2Coordinates_t() for body in bodies]),
        )
        return status, iterations

    return step


def _scheme(name, kind, order, summary, step_seconds, style, options=()):
    return Scheme(
        name=name,
        summary=f"Exudyn {summary}",
        step_seconds=step_seconds,
        order=order,
        implicit=kind.implicit,
        keeps=(),
        options=options,
        run_bodies_inplace=make_batch_entry(_stepper(kind), _starter(kind, name), n_work=1),
        reference="Gerstmayr, Exudyn, Multibody System Dynamics 2023; Arnold & Bruls, "
        "Multibody System Dynamics 2007; Holzinger & Gerstmayr, Multibody System "
        "Dynamics 2021",
        origin=f"rbstudy's adapter of Exudyn {VERSION}",
        code_digest=f"exudyn {VERSION}",  # another Exudyn: other parts
        style=style,
    )


GENALPHA = _scheme(
    "exudyn_genalpha",
    _Kind(exudyn.DynamicSolverType.GeneralizedAlpha, euler_parameters=True),
    2,
    "generalized alpha (implicit) on Euler parameters",
    1.2e-05,
    Style("darkgreen", "p", "-."),
    (SPECTRAL_RADIUS_OPTION,),
)
RK44 = _scheme(
    "exudyn_rk44",
    _Kind(exudyn.DynamicSolverType.RK44, euler_parameters=False),
    4,
    "RK44 (explicit, Lie group) on a rotation vector",
    1.2e-05,
    # rkmk4 to O(h^5), which is not 3 digits at the finest steps: solid, with large
    # hollow markers, under rkmk4's dashed line; slate, where crimson read as rk4's red
    Style("darkslategray", "8", "-"),
)
MIDPOINT = _scheme(
    "exudyn_midpoint",
    _Kind(exudyn.DynamicSolverType.ExplicitMidpoint, euler_parameters=False),
    2,
    "explicit midpoint (Lie group) on a rotation vector",
    9.3e-06,
    Style("slateblue", "H", "--"),
)
