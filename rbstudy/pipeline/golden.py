"""The golden set of `rbstudy conformance`: fixed studies that any integrator is judged on.

Each `GoldenCase` is a free body with an exact reference (the symmetric top in closed form,
every asymmetric body by the exact flow), swept over four time steps, each half the one
before, and names the pass rules that apply to it (`rbstudy.analysis.conformance`):

- `abaqus_top`: the Abaqus force-free benchmark, the flat disk I = (1, 1, 2).
- `hlw_asymmetric`: Hairer, Lubich and Wanner's free rigid body, I = (2, 1, 2/3), which
  breaks the triangle inequality (a numerical stress body, `allow_unphysical`).
- `asymmetric`: a physical asymmetric body, I = (1, 2, 3).
- `t_handle`: a spin about the intermediate axis of a T-handle, which flips every few
  seconds (Dzhanibekov); judged on its flip interval too.
- `near_separatrix`: a body tumbling just inside the separatrix, where the flow is slowest
  to resolve.
- `high_spin`: a disk at 60 rad/s, dt |w| = 0.4 at the largest step.
- `thin_fast`: a thin rod spinning fast about its long axis, the inertia of MuJoCo issue
  3553 (1.7231e-4, 6.58e-6, 1.7243e-4 kg m^2) at dt = 1e-3 s and below.
- `radioss_assembly`: a body assembled from a master node and secondary nodes, as Radioss
  builds one (principal axes and inertias derived).

The peers' own public test cases follow, each with the `Figure` its source asserts, which the
card checks every scheme against (docs/results.md gives the sources' lines):

- `radioss_rota`: OpenRadioss's QA case ``KIN_CONSTRAINTS/RBODY/ROTA``.
- `drake_free_body`: Drake's free-body benchmark against Kane and Levinson's closed form.
- `drake_floating_body`: Drake's test of its quaternion floating mobilizer, the same body
  falling under gravity, against the closed forms at 10 s.
- `exudyn_heavy_top`: Exudyn's test of its explicit Lie-group integrators, a heavy top
  released free under its weight (no exact reference: rbstudy's DOP853 is its reference).

`write_golden` writes each as a study config (``conformance_<case>.yaml``), which a user can
read and rerun with `rbstudy sweep`; `run_golden` sweeps them like any study, so that an
interrupted run resumes and a finished one is reused.

Every golden study sweeps the failure rule's **baseline** too (`baseline`): rbstudy's own
fixed-step schemes of the nominal orders judged. A scheme's failures are compared with them
alone, so its card is the same whatever else is judged beside it. They are run rather than
shipped as a table of failure times: a table would hold for one `--steps` and one version
of the schemes, and fall silently out of date with either; the run costs the baseline's
share of the sweep (docs/architecture.md gives the figures).
"""

import math
import os
import pathlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml

from rbstudy.archive.files import write_text_atomic
from rbstudy.errors import RbstudyError
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.physics.analytic import symmetric_top
from rbstudy.physics.quaternions import quat_to_matrix
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.estimate import duration_text, estimate
from rbstudy.pipeline.execute import run_study
from rbstudy.pipeline.progress import Progress
from rbstudy.schemes import BUILTIN, get_scheme

__all__ = [
    "Check",
    "Figure",
    "GoldenCase",
    "GOLDEN",
    "GOLDEN_PREFIX",
    "baseline",
    "write_golden",
    "run_golden",
]

# What names a golden case's study (and its folder and config): conformance_<case>.
GOLDEN_PREFIX = "conformance_"


@dataclass(frozen=True)
class Check:
    """One number a source asserts: its ``measure`` (a name of
    `rbstudy.analysis.conformance.FIGURE_MEASURES`) is ``expected`` within ``tolerance``
    plus ``growth`` per second of simulated time, at the time ``at`` (s), or at every saved
    time when None."""

    measure: str
    expected: float
    tolerance: float
    growth: float = 0.0
    at: float | None = None


@dataclass(frozen=True)
class Figure:
    """What a peer's public test asserts of a golden case: ``claim`` (a line), the ``url``
    of the test and its ``checks``, judged at the case's own (largest) step, the source's.
    ``scheme``: the one scheme whose own output the figure is (an engine's integrator, to
    its truncation error); None for a property of the motion, asked of every scheme."""

    claim: str
    url: str
    checks: tuple[Check, ...]
    scheme: str | None = None


@dataclass(frozen=True)
class GoldenCase:
    """A study of the golden set: its ``scene`` (a config's scene mapping), the largest
    time step ``dt`` (s; the sweep halves it three times), the output ``interval`` (s), the
    ``rules`` that judge it (names of `rbstudy.analysis.conformance.RULES`), the
    ``figure`` its source asserts (None: a case of rbstudy's own, asserting no number) and,
    for a case that judges no order, the ``steps`` it sweeps whatever ``--steps`` asks (None:
    those)."""

    name: str
    title: str
    scene: dict[str, Any]
    dt: float
    interval: float
    rules: tuple[str, ...] = ("order", "invariants", "energy", "failure")
    figure: Figure | None = None
    steps: int | None = None

    @property
    def moment_free(self) -> bool:
        """No moment acts on the body: a load held over a step, as an engine's caller holds
        it (`rbstudy.schemes.Scheme.loads_held`), then turns it exactly."""
        return scene_from_mapping(self.scene, source=self.name).loads.moment_free


def _body(
    inertia: Sequence[float],
    omega: Sequence[float],
    duration: float,
    unphysical: bool = False,
    momentum_axis: Sequence[float] | None = None,
) -> dict[str, Any]:
    body: dict[str, Any] = {"mass": 1.0, "inertia": list(inertia)}
    if unphysical:
        body["allow_unphysical"] = True
    initial: dict[str, Any] = {"angular_velocity": {"body": list(omega)}}
    if momentum_axis is not None:
        initial["orientation"] = {"momentum_axis": list(momentum_axis)}
    return {"body": body, "initial": initial, "duration": duration}


# HLW's initial angular momentum (cos 1.1, 0, sin 1.1) in body axes, as an angular velocity
_HLW = (2.0, 1.0, 2.0 / 3.0)
_HLW_OMEGA = (math.cos(1.1) / _HLW[0], 0.0, math.sin(1.1) / _HLW[2])

# OpenRadioss QA ROTA (BLOCK_0000.rad): a rigid body of spherical inertia J = 1 (ISPHER = 1,
# no added mass) on master node 1 at the origin, secondary node 2 at (1, 0, 0); the nodes carry
# no mass (the run's total mass is Radioss's floor, 1e-20 kg), so the secondary adds no
# inertia and J = 1 is the whole body's. Its master turns at w_z = 2 rad/s (an imposed
# velocity, which a free spherical body keeps by itself) for 10 s at dt = 1e-3 s.
_ROTA_URL = "https://github.com/OpenRadioss/OpenRadioss/tree/main/qa-tests/miniqa/KIN_CONSTRAINTS/RBODY/ROTA"
_ROTA_SPIN, _ROTA_DURATION, _ROTA_DT = 2.0, 10.0, 1e-3
# A spherical body turns at a constant rate: most schemes are exact on it to round-off at
# these steps (w dt = 0.002), which shows no order to judge; so the case sweeps the source's
# step alone (halvings would cost engine schemes 15 times its 1e4 steps, ~5 minutes for 22
# schemes on 2 cores, to show nothing more).
_NO_ORDER = ("invariants", "energy", "failure")
# ref.extract prints the energy to five figures (2.0000e+00): within half its last digit.
_ROTA_ENERGY_TOLERANCE = 5e-5
# Drake's multibody_plant_free_body_test.cc: a uniform cylinder, I = 0.04 transverse,
# J = 0.02 axial (free_body.h), w_B(0) = (2, 4, 6) rad/s, integrated to t_final = max(4
# periods, 10 s) = 10 s in steps of at most a sixteenth of a period (0.073 s); at every step
# the quaternion's components within tol(t) and w_B within 2 tol(t), where tol(t) = (1 + 4 *
# 256 t / t_final) 1e-3, and the rotation matrices' elements within tol(t). An element of
# the difference of two rotation matrices, and twice a quaternion component's, is at most
# the angle between them: the card asks the orientation error (rad) to stay within tol(t) and
# |w - w_exact| (rad/s) within 2 tol(t), no looser than Drake's test.
_DRAKE_URL = (
    "https://github.com/RobotLocomotion/drake/blob/master/multibody/benchmarks/"
    "free_body/test/multibody_plant_free_body_test.cc"
)
_DRAKE_INERTIA, _DRAKE_OMEGA, _DRAKE_DURATION = (0.04, 0.04, 0.02), (2.0, 4.0, 6.0), 10.0
_DRAKE_TOLERANCE, _DRAKE_GROWTH = 1e-3, 4 * 256 * 1e-3 / _DRAKE_DURATION
# The card's largest step: within Drake's largest (a sixteenth of a period, 0.073 s), which
# its error-controlled RK3 (1e-3 a step) shortens further.
_DRAKE_DT = 1.0 / 32.0

# Drake's multibody/tree/test/floating_body_test.cc (QuaternionFloatingMobilizer.Simulation):
# the same cylinder (free_body.h), mass 1 kg, from the world's orientation at w_WB(0) = (1, 1,
# 1) rad/s and v(0) = (1, 0, 0) m/s, falling under g = 9.81 m/s^2 along -z, integrated to 10 s
# by its error-controlled RK3 (accuracy 1e-5, steps of at most 0.1 s). At 10 s it asserts
# R_WB, p_WBcm, w_WB and v_WBcm against Kane and Levinson's closed form and the parabola by
# CompareMatrices(..., 1e-5, relative): each element within 1e-5 max(1, |its value|). The card
# asks the orientation error (rad, which bounds every element of the matrices' difference)
# within 1e-5 and each component of w_WB and p_WBcm within the test's own allowance; v_WBcm
# is not archived, and the test's quaternion-norm assertion (|q| within 5e-9 of 1) is of
# Drake's unnormalised state, which the archive's unit quaternion does not keep.
_FLOATING_URL = (
    "https://github.com/RobotLocomotion/drake/blob/master/multibody/tree/test/floating_body_test.cc"
)
_FLOATING_OMEGA, _FLOATING_VELOCITY, _FLOATING_GRAVITY = (1.0, 1.0, 1.0), (1.0, 0.0, 0.0), 9.81
_FLOATING_DURATION, _FLOATING_TOLERANCE = 10.0, 1e-5
# The card's largest step: an eighth of Drake's largest (0.1 s), which its error control
# shortens further; fixed-step RK3 reproduces the figure there, and rbstudy's fourth-order
# schemes stay above round-off down to its third halving (6e-10 to 2e-9 rad at 1/80 s, 2e-13
# to 6e-13 at 1/640 s).
_FLOATING_DT = 0.1 / 8


def _drake_compared(measure: str, expected: float) -> Check:
    """A `Check` of ``measure`` at 10 s as Drake's CompareMatrices(..., 1e-5, relative) asks
    each element: within 1e-5 max(1, |expected|)."""
    return Check(measure, expected, _FLOATING_TOLERANCE * max(1.0, abs(expected)), at=_FLOATING_DURATION)


def _floating_checks() -> tuple[Check, ...]:
    """The checks of Drake's floating-body test: the orientation, then w_WB and p_WBcm
    component by component, against the closed forms at 10 s."""
    quaternion, omega = symmetric_top(
        _DRAKE_INERTIA, (0.0, 0.0, 0.0, 1.0), _FLOATING_OMEGA, [_FLOATING_DURATION]
    )
    omega_space = quat_to_matrix(quaternion[0]) @ omega[0]
    position = (
        np.asarray(_FLOATING_VELOCITY) * _FLOATING_DURATION
        - 0.5 * np.array([0.0, 0.0, _FLOATING_GRAVITY]) * _FLOATING_DURATION**2
    )
    return (
        Check("orientation_error", 0.0, _FLOATING_TOLERANCE, at=_FLOATING_DURATION),
        *(
            _drake_compared(f"omega_space_{axis}", float(value))
            for axis, value in zip("xyz", omega_space, strict=True)
        ),
        *(
            _drake_compared(f"position_{axis}", float(value))
            for axis, value in zip("xyz", position, strict=True)
        ),
    )


# Exudyn's TestModels/explicitLieGroupIntegratorTest.py: a body of mass 15 with a heavy top's
# inertia about its fixed point, free, its weight at the body point (0, 1, 0), spun at (0,
# 150, -4.61538) rad/s; its comment gives the y component of the angular velocity in space
# at t = 2 s from its RK44 at h = 1e-3 s, printed to 17 figures: reproduced to 1e-10 rad/s
# (a relative 1e-12, room for another build's round-off; exudyn_rk44 gives it to 3e-14).
_EXUDYN_URL = (
    "https://github.com/jgerstmayr/EXUDYN/blob/HEAD/main/pythonDev/TestModels/"
    "explicitLieGroupIntegratorTest.py"
)
_EXUDYN_MASS, _EXUDYN_DURATION, _EXUDYN_DT = 15.0, 2.0, 1e-3
_EXUDYN_OMEGA_Y, _EXUDYN_TOLERANCE = -106.16651966442174, 1e-10

GOLDEN = (
    GoldenCase(
        "abaqus_top",
        "Abaqus force-free symmetric top (I = 1, 1, 2)",
        _body((1.0, 1.0, 2.0), (0.25, 0.0, 2.0 * math.pi), 2.0, momentum_axis=(0.0, 0.0, 1.0)),
        dt=0.01,
        interval=0.01,
    ),
    GoldenCase(
        "hlw_asymmetric",
        "Hairer-Lubich-Wanner free body (I = 2, 1, 2/3; unphysical)",
        _body(_HLW, _HLW_OMEGA, 10.0, unphysical=True),
        dt=0.1,
        interval=0.1,
    ),
    GoldenCase(
        "asymmetric",
        "Asymmetric free body (I = 1, 2, 3)",
        _body((1.0, 2.0, 3.0), (1.0, 0.5, 2.0), 10.0),
        dt=0.05,
        interval=0.05,
    ),
    GoldenCase(
        "t_handle",
        "T-handle about its intermediate axis (I = 1, 2, 3), flipping",
        _body((1.0, 2.0, 3.0), (0.01, 2.0, 0.01), 40.0),
        dt=0.05,
        interval=0.05,
        rules=("order", "invariants", "energy", "failure", "flip"),
    ),
    GoldenCase(
        "near_separatrix",
        "Near the separatrix (I = 1, 2, 3)",
        _body((1.0, 2.0, 3.0), (1.0, 2.0, 1.0), 10.0),
        dt=0.025,
        interval=0.05,
    ),
    GoldenCase(
        "high_spin",
        "Flat disk at 60 rad/s (dt |w| from 0.4, halved)",
        _body((1.0, 1.0, 2.0), (0.5, 0.0, 60.0), 1.0),
        dt=0.00625,
        interval=0.0125,
    ),
    GoldenCase(
        "thin_fast",
        "Thin rod spinning about its long axis (MuJoCo issue 3553)",
        _body((1.7231e-4, 6.58e-6, 1.7243e-4), (0.5, 60.0, 0.5), 2.0),
        dt=0.002,
        interval=0.01,
    ),
    GoldenCase(
        "radioss_assembly",
        "Radioss rigid body: a master node and five secondaries",
        {
            "assembly": {
                "master": {"position": [0.0, 0.0, 0.0], "mass": 0.5},
                "nodes": {
                    "a": {"position": [0.3, 0.0, 0.0], "mass": 0.2},
                    "b": {"position": [-0.1, 0.2, 0.0], "mass": 0.3},
                    "c": {"position": [0.0, -0.1, 0.15], "mass": 0.25},
                    "d": {"position": [0.2, 0.1, -0.05], "mass": 0.1},
                    "e": {"position": [0.0, 0.0, 0.2], "mass": 0.15},
                },
            },
            "initial": {"angular_velocity": {"body": [2.0, 5.0, 3.0]}},
            "duration": 2.0,
        },
        dt=0.01,
        interval=0.01,
    ),
    GoldenCase(
        "radioss_rota",
        "OpenRadioss QA ROTA: spherical J = 1 at w_z = 2 rad/s, 10 s",
        {
            "assembly": {
                "master": {"position": [0.0, 0.0, 0.0], "mass": 1e-20, "inertia": 1.0},
                "nodes": {"secondary": {"position": [1.0, 0.0, 0.0], "mass": 0.0}},
            },
            "initial": {"angular_velocity": {"body": [0.0, 0.0, _ROTA_SPIN]}},
            "duration": _ROTA_DURATION,
        },
        dt=_ROTA_DT,
        interval=0.1,
        rules=_NO_ORDER,
        steps=1,
        figure=Figure(
            "10,001 cycles; rotational kinetic energy 2.0000 (ref.extract)",
            _ROTA_URL,
            (
                Check("cycles", round(_ROTA_DURATION / _ROTA_DT) + 1, 0.0),
                Check("rotational_energy", 0.5 * _ROTA_SPIN**2, _ROTA_ENERGY_TOLERANCE, at=_ROTA_DURATION),
            ),
        ),
    ),
    GoldenCase(
        "drake_free_body",
        "Drake's free-body benchmark: cylinder I = 0.04, 0.04, 0.02",
        _body(_DRAKE_INERTIA, _DRAKE_OMEGA, _DRAKE_DURATION),
        dt=_DRAKE_DT,
        interval=_DRAKE_DT,
        figure=Figure(
            "quaternion within tol(t), w_B within 2 tol(t), tol(t) = (1 + 102.4 t / s) 1e-3 (the test's own)",
            _DRAKE_URL,
            (
                Check("orientation_error", 0.0, _DRAKE_TOLERANCE, _DRAKE_GROWTH),
                Check("omega_error_magnitude", 0.0, 2 * _DRAKE_TOLERANCE, 2 * _DRAKE_GROWTH),
            ),
        ),
    ),
    GoldenCase(
        "drake_floating_body",
        "Drake's floating body: the cylinder falling, w = (1, 1, 1)",
        {
            "body": {"mass": 1.0, "inertia": list(_DRAKE_INERTIA)},
            "initial": {
                "angular_velocity": {"body": list(_FLOATING_OMEGA)},
                "velocity": list(_FLOATING_VELOCITY),
            },
            "loads": {"gravity": [0.0, 0.0, -_FLOATING_GRAVITY]},
            "duration": _FLOATING_DURATION,
        },
        dt=_FLOATING_DT,
        interval=0.05,
        figure=Figure(
            "at 10 s: R_WB, w_WB and p_WBcm within 1e-5 max(1, |element|) of "
            "the closed forms (the test's own)",
            _FLOATING_URL,
            _floating_checks(),
        ),
    ),
    GoldenCase(
        "exudyn_heavy_top",
        "Exudyn's Lie-group test: a heavy top at 150 rad/s, free",
        {
            "body": {
                "mass": _EXUDYN_MASS,
                "inertia": [0.234375 + _EXUDYN_MASS, 0.46875, 0.234375 + _EXUDYN_MASS],
            },
            "nodes": {"top": [0.0, 1.0, 0.0]},
            "initial": {"angular_velocity": {"body": [0.0, 150.0, -4.61538]}},
            "loads": {"nodes": {"top": {"force_space": [0.0, 0.0, -_EXUDYN_MASS * 9.81]}}},
            "duration": _EXUDYN_DURATION,
        },
        dt=_EXUDYN_DT,
        interval=0.01,
        rules=("order", "failure"),
        figure=Figure(
            "w_y in space at t = 2 s: -106.16651966442174 rad/s (its RK44, h = 1e-3 s)",
            _EXUDYN_URL,
            (Check("omega_space_y", _EXUDYN_OMEGA_Y, _EXUDYN_TOLERANCE, at=_EXUDYN_DURATION),),
            scheme="exudyn_rk44",
        ),
    ),
)


def _study(case: GoldenCase, schemes: Sequence[str], count: int) -> dict[str, Any]:
    return {
        "name": f"{GOLDEN_PREFIX}{case.name}",
        "title": f"conformance: {case.title}",
        "scene": case.scene,
        "output": {"interval": case.interval},
        "run": {"scheme": schemes[0], "dt": case.dt},
        "sweep": {"scheme": list(schemes), "dt": {"halving": case.dt, "count": case.steps or count}},
    }


def baseline(schemes: Iterable[str]) -> list[str]:
    """The schemes that the failure rule compares ``schemes`` (names) with: rbstudy's own
    fixed-step schemes of their nominal orders (group ``builtin``: the published steps are
    judged, not the yardstick), in the registry's order."""
    orders = {get_scheme(name).order for name in schemes}
    return [
        name
        for name, scheme in BUILTIN.items()
        if not scheme.adaptive and scheme.group == "builtin" and scheme.order in orders
    ]


def write_golden(
    folder: str | os.PathLike[str],
    schemes: Sequence[str],
    cases: Iterable[GoldenCase] = GOLDEN,
    steps: int = 4,
) -> list[pathlib.Path]:
    """Write the study config of each of ``cases`` for ``schemes`` and their `baseline` into
    ``folder``, over ``steps`` time steps; returns their paths."""
    folder = pathlib.Path(folder)
    schemes = [*schemes, *(name for name in baseline(schemes) if name not in schemes)]
    paths = []
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for case in cases:
            path = folder / f"{GOLDEN_PREFIX}{case.name}.yaml"
            text = yaml.safe_dump(_study(case, schemes, steps), sort_keys=False)
            if not path.exists() or path.read_text() != text:  # a rerun keeps its archives
                write_text_atomic(text, path)
            paths.append(path)
    except OSError as error:
        raise RbstudyError(
            f"{folder}: cannot write the golden studies there "
            f"({error.strerror}); choose another folder with --out"
        ) from None
    return paths


def run_golden(
    paths: Iterable[str | os.PathLike[str]], out: str | os.PathLike[str], progress: Progress
) -> list[pathlib.Path]:
    """Sweep the golden studies at ``paths`` into ``out``, shown by the one ``progress``
    (`rbstudy.pipeline.progress.Progress`) of them all; returns their archives' paths.

    Each case is said as it starts (``case 3 of 12``), with the kernel time forecast for it
    and for the cases left: `rbstudy.pipeline.estimate`'s, as a sweep's forecast line gives
    it, so that the costs it is made from serve both. A case whose archive is current takes
    none of it: a rerun's forecasts fall as it goes."""
    studies = [load_study(path) for path in paths]
    seconds = [estimate(study).wall_seconds for study in studies]
    archives = []
    for number, study in enumerate(studies, 1):
        name = study.name.removeprefix(GOLDEN_PREFIX)
        own = duration_text(seconds[number - 1])
        said = f"conformance: case {number} of {len(studies)}, {name}: kernels {own}"
        if number < len(studies):
            left = len(studies) - number
            said += f", {duration_text(sum(seconds[number - 1 :]))} with the {left} after it"
        progress.say(said + " (forecast)")
        archives.append(run_study(study, out, progress=progress).path)
    return archives
