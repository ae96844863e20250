"""The one table of output variables, pure metadata: each variable's dimensions, units, CF
names, flags, storage type, and the scene features it needs.

Every variable an archive can hold is an entry of `VARIABLES`; the writer, the reader, the
docs and the contract tests read its attributes from here and nowhere else. The sweep computes
each variable with the `rbstudy.pipeline.outputs` function of the same name
(`rbstudy.pipeline.formulas`): adding a variable is one entry here plus its function.
``needs`` names the scene features (`FEATURES`) a variable requires, so that a variable a
scene does not define is left out instead of filled with NaN. The flag tables come from where
the codes are made: status from the driver (`rbstudy.numerics.state`), reference from the
reference kinds (`rbstudy.physics.analytic`), the accuracy verdict (`VERDICTS`) from here.
The coordinates' metadata is `rbstudy.archive.coordinates`'s.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

# The coordinates' metadata lives in its own module; its names stay importable from here,
# where the pipeline has always read them.
from rbstudy.archive.coordinates import (
    COORDINATES,
    SCHEME_COORDINATES,
    SEARCH_VARIABLES,
    TIME_UNITS,
    cf_attrs,
    coordinate_units,
)
from rbstudy.numerics.state import OK, RESULT_FIELDS, STATUS_NAMES, STATUSES
from rbstudy.physics.analytic import INTEGRATED, REFERENCE_KINDS

if TYPE_CHECKING:
    from rbstudy.physics.scenes import SceneTable

__all__ = [
    "Variable",
    "VARIABLES",
    "DEPRECATED",
    "ALIAS_REMOVED_IN",
    "LONG_NAME_MAX",
    "FEATURES",
    "COORDINATES",
    "SEARCH_VARIABLES",
    "SCHEME_COORDINATES",
    "TIME_UNITS",
    "coordinate_units",
    "cf_attrs",
    "variable_attrs",
    "scene_features",
    "selected",
    "VERDICTS",
    "ACCURATE",
    "INACCURATE",
    "FAILED",
    "UNJUDGED",
    "BOOKKEEPING",
    "COST_MODEL",
    "UNCERTAINTIES",
    "PER_SCENE",
]

# Codes of the accuracy verdict (`accuracy`): a failed case has none, and a finished case
# without a reference (its DOP853 reference passed its step budget) cannot be judged.
VERDICTS = ("accurate", "inaccurate", "failed", "unjudged")
ACCURATE, INACCURATE, FAILED, UNJUDGED = range(len(VERDICTS))

# The scene features a variable may need: name -> (predicate on a
# `rbstudy.physics.scenes.SceneTable`, true or false per scene, meaning).
FEATURES: dict[str, tuple[Callable[[SceneTable], np.ndarray], str]] = {
    "nodes": (
        lambda scenes: np.full(len(scenes), len(scenes.node_names) > 0),
        "the scene has nodes fixed to the body",
    ),
    "translation": (lambda scenes: scenes.translates, "the centre of mass moves"),
    "reference": (
        lambda scenes: np.full(len(scenes), True),
        "a reference solution (closed form, or integrated where none exists)",
    ),
    # any scene of the study: the closed-form cases of a mixed study hold NaN
    "integrated": (
        lambda scenes: np.full(len(scenes), bool(np.any(scenes.reference_kinds == INTEGRATED))),
        "some scene has no closed-form reference: it is integrated twice, and the two are compared",
    ),
    "closed_form": (
        lambda scenes: np.full(len(scenes), bool(np.any(scenes.reference_kinds != INTEGRATED))),
        "some scene has a closed-form reference, whose sensitivity to its initial data sets a float64 floor",
    ),
    "moment_free": (
        lambda scenes: scenes.moment_free,
        "no moment acts: energy and angular momentum are conserved, so their drift is an error",
    ),
    "symmetric": (
        lambda scenes: scenes.moment_free & (scenes.symmetry_axes >= 0),
        "a moment-free symmetric body (precession frequency)",
    ),
    "asymmetric": (
        lambda scenes: scenes.moment_free & (scenes.symmetry_axes < 0),
        "a moment-free body with three different inertias (flip interval)",
    ),
    "assembled": (
        lambda scenes: np.full(len(scenes), scenes.regularised is not None),
        "a body assembled from a master node and secondary nodes",
    ),
}


@dataclass(frozen=True, kw_only=True)
class Variable:
    """An output variable: ``dims`` beyond the case dimensions, CF ``units``, a ``long_name``
    short enough for a plot's axis label (`LONG_NAME_MAX`) and the ``description`` that
    explains it, the scene features it ``needs``, its netCDF storage type, for a flag the
    meaning of each code (``flags``), and whether it is the same for every run of a scene
    (``per_scene``: stored along the scene's dimensions only, not along scheme, dt or a
    scheme option). Built by keyword."""

    name: str
    dims: tuple
    units: str
    long_name: str
    description: str
    needs: frozenset = frozenset()
    dtype: str = "f8"
    flags: tuple = ()
    per_scene: bool = False


# xarray labels a plot's axis "long_name [units]": longer names are cut or wrap.
LONG_NAME_MAX = 60


def _v(*, name, dims, units, long_name, description, needs=(), flags=(), dtype="f8", per_scene=False):
    """A variable computed per case (by the `rbstudy.pipeline.outputs` function of its name)."""
    return Variable(
        name=name,
        dims=dims,
        units=units,
        long_name=long_name,
        description=description,
        needs=frozenset(needs),
        dtype=dtype,
        flags=flags,
        per_scene=per_scene,
    )


def _scene(**fields):
    """A variable of the scene alone, the same for every scheme, dt and option (`_v`'s fields)."""
    return _v(**fields, per_scene=True)


def _result(*, name, **fields):
    """A per-case result of the driver, one value a case, stored as the driver's storage type
    (`_v`'s other fields)."""
    return _v(name=name, dims=(), dtype=dict(RESULT_FIELDS)[name], **fields)


_AS_UNCERTAINTY = "; NaN where reference_uncertainty is"

VARIABLES = {
    v.name: v
    for v in (
        _v(
            name="omega_body",
            dims=("time", "axis"),
            units="rad s-1",
            long_name="angular velocity in principal body axes",
            description="angular velocity w in the principal axes of the body",
        ),
        _v(
            name="omega_space",
            dims=("time", "axis"),
            units="rad s-1",
            long_name="angular velocity in space axes",
            description="angular velocity R w in the space (global) axes",
        ),
        _v(
            name="quaternion",
            dims=("time", "component"),
            units="1",
            long_name="orientation quaternion (x, y, z, w)",
            description="orientation as a unit quaternion, scalar last, that turns the principal body axes "
            "into the space axes",
        ),
        _v(
            name="position",
            dims=("time", "axis"),
            units="m",
            long_name="centre-of-mass position",
            description="position of the centre of mass in space axes",
            needs=("translation",),
        ),
        _v(
            name="node_displacement",
            dims=("time", "node", "axis"),
            units="m",
            long_name="node displacement",
            description="displacement of each node fixed to the body from its position at t = 0, in space "
            "axes",
            needs=("nodes",),
        ),
        _v(
            name="node_velocity",
            dims=("time", "node", "axis"),
            units="m s-1",
            long_name="node velocity",
            description="velocity of each node fixed to the body, v + R (w x s) with s its offset in body "
            "axes, in space axes",
            needs=("nodes",),
        ),
        _v(
            name="energy_error",
            dims=("time",),
            units="1",
            long_name="relative kinetic energy error",
            description="(T - T0) / T0 of the rotational kinetic energy T (no moment acts, so T is "
            "conserved)",
            needs=("moment_free",),
        ),
        _v(
            name="momentum_error",
            dims=("time",),
            units="1",
            long_name="relative angular momentum error",
            description="|L - L0| / |L0| of the angular momentum vector L in space axes (no moment acts, "
            "so L "
            "is conserved)",
            needs=("moment_free",),
        ),
        _v(
            name="orientation_error",
            dims=("time",),
            units="rad",
            long_name="orientation error",
            description="geodesic angle between the orientation and the reference's (variable reference)",
            needs=("reference",),
        ),
        _v(
            name="omega_error",
            dims=("time",),
            units="1",
            long_name="relative angular velocity error",
            description="|w - w_ref| / |w_ref| of the angular velocity in body axes against the reference",
            needs=("reference",),
        ),
        _v(
            name="node_error",
            dims=("time", "node"),
            units="m",
            long_name="node position error",
            description="distance of each node to its position in the reference motion",
            needs=("reference", "nodes"),
        ),
        _v(
            name="precession_frequency",
            dims=(),
            units="rad s-1",
            long_name="body-frame precession frequency",
            description="slope of the unwrapped phase of the angular velocity across the symmetry axis "
            "(w1 + i w2 for axis 3) over the run",
            needs=("symmetric",),
        ),
        _scene(
            name="precession_frequency_exact",
            dims=(),
            units="rad s-1",
            long_name="exact precession frequency",
            description="exact body-frame precession frequency W = w3 (I3 - I1) / I1 (axis 3 the symmetry "
            "axis)",
            needs=("symmetric",),
        ),
        _v(
            name="precession_frequency_error",
            dims=(),
            units="rad s-1",
            long_name="precession frequency error",
            description="precession_frequency minus precession_frequency_exact",
            needs=("symmetric",),
        ),
        _v(
            name="flip_interval",
            dims=(),
            units="s",
            long_name="flip interval",
            description="mean time between sign changes of the angular velocity about the intermediate axis",
            needs=("asymmetric",),
        ),
        _scene(
            name="flip_interval_exact",
            dims=(),
            units="s",
            long_name="exact flip interval",
            description="exact time between sign changes of the intermediate-axis rate, 2 K(k^2) / |lambda|",
            needs=("asymmetric",),
        ),
        _scene(
            name="separatrix_distance",
            dims=(),
            units="1",
            long_name="distance from the separatrix, k'^2",
            description="1 - k^2 of the exact free motion, 0 on the separatrix; near 0 the case is "
            "ill-conditioned (the flip interval grows as ln(4/k'))",
            needs=("asymmetric",),
        ),
        _v(
            name="flip_interval_error",
            dims=(),
            units="s",
            long_name="flip interval error",
            description="flip_interval minus flip_interval_exact",
            needs=("asymmetric",),
        ),
        _v(
            name="flip_count",
            dims=(),
            units="1",
            long_name="flips in the run",
            description="sign changes of the intermediate-axis rate between samples",
            needs=("asymmetric",),
        ),
        _v(
            name="flip_count_exact",
            dims=(),
            units="1",
            long_name="flips of the exact solution",
            description="sign changes of the exact intermediate-axis rate between the same samples",
            needs=("asymmetric",),
        ),
        _result(
            name="status",
            units="1",
            long_name="case outcome",
            description="; ".join(
                [STATUS_NAMES[OK], *(f"{name}: {message}" for name, message, _ in STATUSES[OK + 1 :])]
            ),
            flags=STATUS_NAMES,
        ),
        _result(
            name="failure_time",
            units="s",
            long_name="time of failure",
            description="time of blow-up or solver failure; NaN if none",
        ),
        _result(
            name="n_steps", units="1", long_name="time steps taken", description="time steps the scheme took"
        ),
        _result(
            name="iterations",
            units="1",
            long_name="Newton iterations",
            description="Newton iterations summed over the steps (0 for an explicit scheme)",
        ),
        _v(
            name="run_time",
            dims=(),
            units="s",
            long_name="kernel CPU time per case",
            description="CPU time of the compiled batch call, summed over its threads, divided by the "
            "batch's "
            "cases; compilation excluded",
        ),
        _v(
            name="step_seconds",
            dims=(),
            units="s",
            long_name="calibrated kernel CPU time per body-step",
            description="core-seconds a body-step of the case's scheme and options takes on the machine that "
            "ran it, calibrated once per machine and source tree (rbstudy.pipeline.calibration); "
            "a case costs n_steps times it, the cost the findings rank by",
        ),
        _v(
            name="step_seconds_uncertainty",
            dims=(),
            units="1",
            long_name="relative uncertainty of step_seconds",
            description="half the spread of the calibration's quiet runs relative to their least, at least "
            "the spread between calibrations; BUSY_UNCERTAINTY where the machine stayed busy; costs "
            "within it of each other are a tie",
        ),
        _result(
            name="max_energy_error",
            units="1",
            long_name="largest relative energy error",
            description="largest |(T - T0) / T0| over every step, not only the samples",
            needs=("moment_free",),
        ),
        _result(
            name="max_momentum_magnitude_error",
            units="1",
            long_name="largest relative drift of |L|",
            description="largest relative drift of the magnitude |L| over every step (the vector's drift, "
            "sampled, is momentum_error)",
            needs=("moment_free",),
        ),
        _result(
            name="max_step_angle",
            units="rad",
            long_name="largest step angle dt |w|",
            description="largest dt |w| over the accepted states, t = 0 included (an adaptive scheme: "
            "each step's own dt and the |w| it ends with)",
        ),
        _result(
            name="radioss_dt_limit",
            units="1",
            long_name="OpenRadioss step limit",
            description="whether (dt |w|)^2 > 1 at some step, where OpenRadioss aborts a rigid body as "
            "unstable (the run goes on)",
            flags=("within", "exceeded"),
        ),
        _v(
            name="final_orientation_error",
            dims=(),
            units="rad",
            long_name="final orientation error",
            description="orientation_error at the last output time",
            needs=("reference",),
        ),
        _v(
            name="accuracy",
            dims=(),
            units="1",
            long_name="accuracy verdict",
            description="a finished case is inaccurate when its orientation error at any sample (rad) or its "
            "relative energy or |L| drift passes the global attribute accuracy_bound; a failed "
            "case has no verdict; a finished case without a reference (reference = none) and no "
            "drift past the bound is unjudged",
            needs=("reference",),
            flags=VERDICTS,
            dtype="i1",
        ),
        _scene(
            name="reference",
            dims=(),
            units="1",
            long_name="reference solution",
            description="the solution the errors are measured against",
            needs=("reference",),
            flags=REFERENCE_KINDS,
            dtype="i1",
        ),
        _scene(
            name="reference_uncertainty",
            dims=(),
            units="rad",
            long_name="reference orientation uncertainty",
            description="orientation angle at the last output time between the two independent "
            "integrations of the reference (exact_split composed to order 8, and DOP853); NaN "
            "where the reference is a closed form or was not cross-checked",
            needs=("integrated",),
        ),
        _scene(
            name="float64_floor",
            dims=(),
            units="rad",
            long_name="float64 floor of the orientation",
            description="largest orientation angle at the last output time between the closed form and "
            "itself from initial data one ulp off: what rounding the initial state costs any scheme; "
            "no order is fitted below 3x it (docs/theory.md s6). NaN where the reference is integrated",
            needs=("closed_form",),
        ),
        _scene(
            name="reference_omega_uncertainty",
            dims=(),
            units="1",
            long_name="reference angular velocity uncertainty",
            description="largest relative difference of the angular velocity between the two integrations "
            "of the reference over the output times" + _AS_UNCERTAINTY,
            needs=("integrated",),
        ),
        _scene(
            name="reference_node_uncertainty",
            dims=(),
            units="m",
            long_name="reference node position uncertainty",
            description="largest node distance between the two integrations of the reference over the "
            "output times" + _AS_UNCERTAINTY,
            needs=("integrated", "nodes"),
        ),
        _scene(
            name="inertia",
            dims=("axis",),
            units="kg m2",
            long_name="principal moments of inertia",
            description="moments of inertia about the body's principal axes",
        ),
        _scene(
            name="initial_spin",
            dims=(),
            units="rad s-1",
            long_name="initial angular speed |w(0)|",
            description="magnitude of the angular velocity at t = 0",
        ),
        _scene(
            name="node_offset",
            dims=("node", "axis"),
            units="m",
            long_name="node offset from the centre of mass",
            description="offset of each node fixed to the body from the centre of mass, in principal body "
            "axes",
            needs=("nodes",),
        ),
        _scene(
            name="regularised_inertia",
            dims=(),
            units="1",
            long_name="inertia regularised",
            description="whether a principal inertia below 1e-3 of the largest was raised to that (Radioss "
            "regularisation of an assembled body)",
            needs=("assembled",),
            flags=("as_assembled", "regularised"),
            dtype="i1",
        ),
        _scene(
            name="physical_body",
            dims=(),
            units="1",
            long_name="physical rigid body",
            description="whether the principal inertias meet the triangle inequality (a real rigid body, "
            "not an allow_unphysical stress body)",
            flags=("unphysical_stress_body", "physical"),
            dtype="i1",
        ),
    )
}

# Names replaced by clearer ones in rbstudy 0.2, kept as aliases until `ALIAS_REMOVED_IN`:
# stored beside the new name (same values) and accepted in output.variables. Old name -> new
# name. docs/config.md names the same release.
DEPRECATED = {"max_momentum_error": "max_momentum_magnitude_error"}
ALIAS_REMOVED_IN = "0.5"
VARIABLES.update(
    {
        old: dataclasses.replace(
            VARIABLES[new],
            name=old,
            long_name=f"deprecated alias of {new}",
            description=f"removed in rbstudy {ALIAS_REMOVED_IN}: {VARIABLES[new].description}",
        )
        for old, new in DEPRECATED.items()
    }
)

# The variables stored along the scene's dimensions only.
PER_SCENE = frozenset(name for name, variable in VARIABLES.items() if variable.per_scene)


def variable_attrs(name: str) -> dict[str, Any]:
    """The CF attributes of output variable ``name``, all from the table above."""
    variable = VARIABLES[name]
    described = {"long_name": variable.long_name, "description": variable.description}
    if variable.flags:
        return described | {
            "flag_values": list(range(len(variable.flags))),
            "flag_meanings": " ".join(variable.flags),
        }
    return {"units": variable.units} | described


def scene_features(scenes: SceneTable) -> set[str]:
    """The names of the `FEATURES` every scene of a `rbstudy.physics.scenes.SceneTable` has."""
    return {name for name, (has, _) in FEATURES.items() if has(scenes).all()}


# Per-case bookkeeping stored whatever `output.variables` says: the summary, the figures and
# the report read them (a few numbers per case).
BOOKKEEPING = (
    "status",
    "accuracy",
    "failure_time",
    "n_steps",
    "iterations",
    "run_time",
    "reference",
    "physical_body",
    "inertia",
    "initial_spin",
    "radioss_dt_limit",
)
# The cost model (`rbstudy.pipeline.calibration`), kept whatever `output.variables` says; not
# required of an archive (those before it have none: the findings then cost by run_time).
COST_MODEL = ("step_seconds", "step_seconds_uncertainty")
# The relative uncertainty of a cost measured while other programs kept the machine busy
# (`rbstudy.pipeline.calibration`): other programs changed a scheme's cost by up to half. An
# archive whose costs carry it says so where it recommends.
BUSY_UNCERTAINTY = 0.5
# What a reference can show: the uncertainties of integrated references and the float64
# floor of closed forms, kept whatever `output.variables` says wherever a study defines them:
# the order fits read them.
UNCERTAINTIES = tuple(
    name for name, variable in VARIABLES.items() if variable.needs & {"integrated", "closed_form"}
)


def selected(features: Iterable[str]) -> list[str]:
    """Names of the variables a scene with ``features`` defines, in table order."""
    return [name for name, v in VARIABLES.items() if v.needs <= set(features)]
