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
import pathlib
from dataclasses import dataclass

import yaml

from rbstudy.errors import RbstudyError
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.pipeline.store import write_text_atomic
from rbstudy.schemes import BUILTIN, get_scheme

__all__ = ["GoldenCase", "GOLDEN", "baseline", "write_golden", "run_golden"]


@dataclass(frozen=True)
class GoldenCase:
    """A study of the golden set: its ``scene`` (a config's scene mapping), the largest
    time step ``dt`` (s; the sweep halves it three times), the output ``interval`` (s) and
    the ``rules`` that judge it (names of `rbstudy.analysis.conformance.RULES`)."""

    name: str
    title: str
    scene: dict
    dt: float
    interval: float
    rules: tuple = ("order", "invariants", "energy", "failure")


def _body(inertia, omega, duration, unphysical=False, momentum_axis=None):
    body = {"mass": 1.0, "inertia": list(inertia)}
    if unphysical:
        body["allow_unphysical"] = True
    initial = {"angular_velocity": {"body": list(omega)}}
    if momentum_axis is not None:
        initial["orientation"] = {"momentum_axis": list(momentum_axis)}
    return {"body": body, "initial": initial, "duration": duration}


# HLW's initial angular momentum (cos 1.1, 0, sin 1.1) in body axes, as an angular velocity
_HLW = (2.0, 1.0, 2.0 / 3.0)
_HLW_OMEGA = (math.cos(1.1) / _HLW[0], 0.0, math.sin(1.1) / _HLW[2])

GOLDEN = (
    GoldenCase("abaqus_top", "Abaqus force-free symmetric top (I = 1, 1, 2)",
               _body((1.0, 1.0, 2.0), (0.25, 0.0, 2.0 * math.pi), 2.0,
                     momentum_axis=(0.0, 0.0, 1.0)),
               dt=0.01, interval=0.01),
    GoldenCase("hlw_asymmetric", "Hairer-Lubich-Wanner free body (I = 2, 1, 2/3; unphysical)",
               _body(_HLW, _HLW_OMEGA, 10.0, unphysical=True), dt=0.1, interval=0.1),
    GoldenCase("asymmetric", "Asymmetric free body (I = 1, 2, 3)",
               _body((1.0, 2.0, 3.0), (1.0, 0.5, 2.0), 10.0), dt=0.05, interval=0.05),
    GoldenCase("t_handle", "T-handle about its intermediate axis (I = 1, 2, 3), flipping",
               _body((1.0, 2.0, 3.0), (0.01, 2.0, 0.01), 40.0), dt=0.05, interval=0.05,
               rules=("order", "invariants", "energy", "failure", "flip")),
    GoldenCase("near_separatrix", "Near the separatrix (I = 1, 2, 3)",
               _body((1.0, 2.0, 3.0), (1.0, 2.0, 1.0), 10.0), dt=0.025, interval=0.05),
    GoldenCase("high_spin", "Flat disk at 60 rad/s (dt |w| from 0.4, halved)",
               _body((1.0, 1.0, 2.0), (0.5, 0.0, 60.0), 1.0), dt=0.00625, interval=0.0125),
    GoldenCase("thin_fast", "Thin rod spinning about its long axis (MuJoCo issue 3553)",
               _body((1.7231e-4, 6.58e-6, 1.7243e-4), (0.5, 60.0, 0.5), 2.0), dt=0.002,
               interval=0.01),
    GoldenCase("radioss_assembly", "Radioss rigid body: a master node and five secondaries",
               {"assembly": {"master": {"position": [0.0, 0.0, 0.0], "mass": 0.5},
                             "nodes": {"a": {"position": [0.3, 0.0, 0.0], "mass": 0.2},
                                       "b": {"position": [-0.1, 0.2, 0.0], "mass": 0.3},
                                       "c": {"position": [0.0, -0.1, 0.15], "mass": 0.25},
                                       "d": {"position": [0.2, 0.1, -0.05], "mass": 0.1},
                                       "e": {"position": [0.0, 0.0, 0.2], "mass": 0.15}}},
                "initial": {"angular_velocity": {"body": [2.0, 5.0, 3.0]}},
                "duration": 2.0},
               dt=0.01, interval=0.01),
)


def _study(case, schemes, count):
    return {"name": f"conformance_{case.name}", "title": f"conformance: {case.title}",
            "scene": case.scene, "output": {"interval": case.interval},
            "run": {"scheme": schemes[0], "dt": case.dt},
            "sweep": {"scheme": list(schemes), "dt": {"halving": case.dt, "count": count}}}


def baseline(schemes):
    """The schemes that the failure rule compares ``schemes`` (names) with: rbstudy's own
    fixed-step schemes of their nominal orders, in the registry's order."""
    orders = {get_scheme(name).order for name in schemes}
    return [name for name, scheme in BUILTIN.items()
            if not scheme.adaptive and scheme.order in orders]


def write_golden(folder, schemes, cases=GOLDEN, steps=4):
    """Write the study config of each of ``cases`` for ``schemes`` and their `baseline` into
    ``folder``, over ``steps`` time steps; returns their paths."""
    folder = pathlib.Path(folder)
    schemes = [*schemes, *(name for name in baseline(schemes) if name not in schemes)]
    paths = []
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for case in cases:
            path = folder / f"conformance_{case.name}.yaml"
            text = yaml.safe_dump(_study(case, schemes, steps), sort_keys=False)
            if not path.exists() or path.read_text() != text:  # a rerun keeps its archives
                write_text_atomic(text, path)
            paths.append(path)
    except OSError as error:
        raise RbstudyError(f"{folder}: cannot write the golden studies there "
                           f"({error.strerror}); choose another folder with --out") from None
    return paths


def run_golden(paths, out, progress):
    """Sweep the golden studies at ``paths`` into ``out``, shown by the one ``progress``
    (`rbstudy.pipeline.progress.Progress`) of them all; returns their archives' paths."""
    return [run_study(load_study(path), out, progress=progress).path for path in paths]
