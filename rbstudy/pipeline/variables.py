"""The one table of output variables: each bound to the function that computes it, with its
dimensions, units, CF names, flags, and the scene features it needs.

Every variable the archive can hold is an entry of `VARIABLES`; the store reads its
attributes from here and nowhere else, and `evaluate` computes a batch's variables through
the bound functions (`rbstudy.pipeline.outputs`). Adding a variable is one entry here plus
its function. ``needs`` names the scene features (`FEATURES`) a variable requires, so that a
variable a scene does not define is left out instead of filled with NaN. The flag tables come
from where the codes are made: status from the driver (`rbstudy.numerics.state`), reference
from the reference kinds (`rbstudy.physics.analytic`).
"""

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rbstudy.numerics.state import RESULT_FIELDS, STATUS_NAMES
from rbstudy.physics.analytic import INTEGRATED, REFERENCE_KINDS
from rbstudy.pipeline import outputs

__all__ = ["Variable", "VARIABLES", "DEPRECATED", "FEATURES", "COORDINATES", "SCHEME_COORDINATES",
           "TIME_UNITS", "coordinate_units", "cf_attrs", "variable_attrs", "scene_features", "selected",
           "evaluate", "BOOKKEEPING", "UNCERTAINTIES"]

# The scene features a variable may need: name -> (predicate on a
# `rbstudy.physics.scenes.SceneTable`, true or false per scene, meaning).
FEATURES = {
    "nodes": (lambda scenes: np.full(len(scenes), len(scenes.node_names) > 0),
              "the scene has nodes fixed to the body"),
    "translation": (lambda scenes: scenes.translates, "the centre of mass moves"),
    "reference": (lambda scenes: np.full(len(scenes), True),
                  "a reference solution (closed form, or integrated where none exists)"),
    # any scene of the study: the closed-form cases of a mixed study hold NaN
    "integrated": (lambda scenes: np.full(len(scenes), bool(np.any(
        scenes.reference_kinds == INTEGRATED))),
                   "some scene has no closed-form reference: it is integrated twice, and the "
                   "two are compared"),
    "moment_free": (lambda scenes: scenes.moment_free,
                    "no moment acts: energy and angular momentum are conserved, so their "
                    "drift is an error"),
    "symmetric": (lambda scenes: scenes.moment_free & (scenes.symmetry_axes >= 0),
                  "a moment-free symmetric body (precession frequency)"),
    "asymmetric": (lambda scenes: scenes.moment_free & (scenes.symmetry_axes < 0),
                   "a moment-free body with three different inertias (flip interval)"),
    "assembled": (lambda scenes: np.full(len(scenes), scenes.regularised is not None),
                  "a body assembled from a master node and secondary nodes"),
}


@dataclass(frozen=True)
class Variable:
    """An output variable: ``compute(batch) -> values`` (case axis first), ``dims`` beyond the
    case dimensions, CF ``units`` and ``long_name``, the scene features it ``needs``, its
    netCDF storage type, and for a flag the meaning of each code (``flags``)."""

    name: str
    dims: tuple
    units: str
    long_name: str
    compute: Callable
    needs: frozenset = frozenset()
    dtype: str = "f8"
    flags: tuple = ()


def _v(name, dims, units, long_name, *needs, flags=(), dtype="f8"):
    """A variable computed by `rbstudy.pipeline.outputs` function of the same name."""
    return Variable(name, dims, units, long_name, getattr(outputs, name), frozenset(needs),
                    dtype, flags)


def _result(name, units, long_name, *needs, flags=()):
    """A per-case result of the driver, stored as the driver's storage type."""
    return Variable(name, (), units, long_name, outputs.driver_result(name), frozenset(needs),
                    dict(RESULT_FIELDS)[name], flags)


VARIABLES = {v.name: v for v in (
    _v("omega_body", ("time", "axis"), "rad s-1", "angular velocity in principal body axes"),
    _v("omega_space", ("time", "axis"), "rad s-1", "angular velocity in space axes"),
    _v("quaternion", ("time", "component"), "1",
       "orientation quaternion, scalar-last (x, y, z, w), principal body axes to space"),
    _v("position", ("time", "axis"), "m", "centre-of-mass position", "translation"),
    _v("node_displacement", ("time", "node", "axis"), "m",
       "displacement of nodes fixed to the body", "nodes"),
    _v("node_velocity", ("time", "node", "axis"), "m s-1",
       "velocity of nodes fixed to the body, v + w x r, in space axes", "nodes"),
    _v("energy_error", ("time",), "1", "relative rotational kinetic energy error (T - T0) / T0",
       "moment_free"),
    _v("momentum_error", ("time",), "1", "relative space angular momentum error |L - L0| / |L0|",
       "moment_free"),
    _v("orientation_error", ("time",), "rad", "geodesic angle to the reference orientation",
       "reference"),
    _v("omega_error", ("time",), "1", "relative angular velocity error |w - w_ref| / |w_ref|",
       "reference"),
    _v("node_error", ("time", "node"), "m", "distance of nodes to their reference positions",
       "reference", "nodes"),
    _v("precession_frequency", (), "rad s-1",
       "body-frame precession frequency: slope of the unwrapped phase of w1 + i w2", "symmetric"),
    _v("precession_frequency_exact", (), "rad s-1",
       "exact body-frame precession frequency W = w3 (I3 - I1) / I1", "symmetric"),
    _v("precession_frequency_error", (), "rad s-1",
       "precession frequency minus its exact value", "symmetric"),
    _v("flip_interval", (), "s",
       "mean time between sign changes of the intermediate-axis angular velocity",
       "asymmetric"),
    _v("flip_interval_exact", (), "s", "exact flip interval 2 K(k^2) / |lambda|", "asymmetric"),
    _v("flip_interval_error", (), "s", "flip interval minus its exact value", "asymmetric"),
    _result("status", "1", "case outcome", flags=STATUS_NAMES),
    _result("failure_time", "s", "time of blow-up or solver failure (NaN if none)"),
    _result("n_steps", "1", "time steps taken"),
    _result("iterations", "1", "Newton iterations summed over the steps"),
    _v("run_time", (), "s", "kernel CPU time per case: CPU time of the compiled batch call, "
       "summed over its threads, / batch size; compilation excluded"),
    _result("max_energy_error", "1", "largest |relative energy error| over every step",
            "moment_free"),
    _result("max_momentum_magnitude_error", "1",
            "largest relative drift of the magnitude |L| over every step (the vector's drift, "
            "sampled, is momentum_error)", "moment_free"),
    _result("max_step_angle", "rad", "largest dt |w| over the accepted states, t = 0 included "
            "(an adaptive scheme: each step's own dt and the |w| it ends with)"),
    _result("radioss_dt_limit", "1", "whether (dt |w|)^2 > 1 at some step, where OpenRadioss "
            "aborts a rigid body as unstable (the run goes on)",
            flags=("within", "exceeded")),
    _v("final_orientation_error", (), "rad", "orientation error at the last output time",
       "reference"),
    _v("accuracy", (), "1", "accuracy verdict: a finished case is inaccurate when its "
       "orientation error at any sample (rad) or its relative energy or |L| drift passes the "
       "global attribute accuracy_bound; a failed case has no verdict; a finished case "
       "without a reference (reference = none) and no drift past the bound is unjudged",
       "reference",
       flags=outputs.VERDICTS, dtype="i1"),
    _v("reference", (), "1", "reference solution the errors are measured against", "reference",
       flags=REFERENCE_KINDS, dtype="i1"),
    _v("reference_uncertainty", (), "rad", "orientation angle at the last output time "
       "between the two independent integrations of the reference (exact_split composed to "
       "order 8, and DOP853); NaN where the reference is a closed form or was not "
       "cross-checked", "integrated"),
    _v("reference_omega_uncertainty", (), "1", "largest relative difference of the angular "
       "velocity between the two integrations of the reference over the output times (as "
       "reference_uncertainty)",
       "integrated"),
    _v("reference_node_uncertainty", (), "m", "largest node distance between the two "
       "integrations of the reference over the output times (as reference_uncertainty)",
       "integrated", "nodes"),
    _v("inertia", ("axis",), "kg m2", "principal moments of inertia"),
    _v("initial_spin", (), "rad s-1", "initial angular speed |w(0)|"),
    _v("node_offset", ("node", "axis"), "m", "node offsets from the centre of mass, principal axes",
       "nodes"),
    _v("regularised_inertia", (), "1", "whether a principal inertia below 1e-3 of the largest "
       "was raised to that (Radioss regularisation of an assembled body)", "assembled",
       flags=("as_assembled", "regularised"), dtype="i1"),
    _v("physical_body", (), "1",
       "whether the principal inertias meet the triangle inequality (a real rigid body)",
       flags=("unphysical_stress_body", "physical"), dtype="i1"),
)}

# Names replaced by clearer ones in rbstudy 0.2, kept as aliases until 0.4: stored beside the
# new name (same values) and accepted in output.variables. Old name -> new name.
DEPRECATED = {"max_momentum_error": "max_momentum_magnitude_error"}
VARIABLES.update({old: dataclasses.replace(
    VARIABLES[new], name=old, long_name=f"deprecated alias of {new}, removed in rbstudy "
                                        f"0.3: {VARIABLES[new].long_name}")
    for old, new in DEPRECATED.items()})

# Simulated time is a duration, not a date: plain seconds, which every reader (xarray
# included) opens as numbers. (A "seconds since <epoch>" unit made xarray decode it to
# calendar dates.)
TIME_UNITS = "s"

# Coordinates: the output grid and the named sweep axes. (units, long_name); units None for
# labels.
COORDINATES = {
    "time": (TIME_UNITS, "simulated time since the start of the run"),
    "axis": (None, "vector component"),
    "component": (None, "quaternion component, scalar last"),
    "node": (None, "node name"),
    "scheme": (None, "integration scheme"),
    "dt": ("s", "time step"),
    "inertia_ratio": ("1", "inertia ratio I3 / I1 of the symmetric body"),
    "spin": ("rad s-1", "initial angular speed |w|"),
    "tilt": ("degree", "initial angle between w and the body symmetry axis 3"),
}

# What the archive records of each scheme, beside the `scheme` coordinate, so that the
# summary, figures and report never need the registry (nor a compiler): name ->
# (Scheme attribute, units, long_name).
SCHEME_COORDINATES = {
    "nominal_order": ("order", "1", "nominal global order of accuracy of the scheme"),
    "claimed_invariants": ("keeps", None,
                           "invariants the scheme keeps to round-off for a moment-free body"),
    "scheme_origin": ("origin", None,
                      "who provides the scheme: rbstudy, or a plug-in's package and version"),
}

# Units of a value swept by dotted path, found from the last key of the path that is listed
# here (``scene.initial.angular_velocity.body.2`` -> ``body`` under ``angular_velocity``).
_KEY_UNITS = {
    "mass": "kg", "inertia": "kg m2", "angular_velocity": "rad s-1", "position": "m",
    "velocity": "m s-1", "euler_zxz_deg": "degree", "phi_deg": "degree", "quaternion": "1",
    "rotation_vector": "rad", "momentum_axis": "1", "nodes": "m", "force_space": "N",
    "force_body": "N", "moment_space": "N m", "moment_body": "N m", "gravity": "m s-2",
    "alpha": "1", "axis_order": None,
}


def coordinate_units(target):
    """Units of the values of a sweep axis (short name or dotted path), None if a label."""
    if target in COORDINATES:
        return COORDINATES[target][0]
    for key in reversed(target.split(".")):
        if key in _KEY_UNITS:
            return _KEY_UNITS[key]
    return None


def cf_attrs(units, long_name):
    """CF ``long_name`` and, for a quantity with units, ``units``."""
    return {"long_name": long_name} | ({"units": units} if units else {})


def variable_attrs(name):
    """The CF attributes of output variable ``name``, all from the table above."""
    variable = VARIABLES[name]
    if variable.flags:
        return {"long_name": variable.long_name,
                "flag_values": list(range(len(variable.flags))),
                "flag_meanings": " ".join(variable.flags)}
    return {"units": variable.units, "long_name": variable.long_name}


def scene_features(scenes):
    """The names of the `FEATURES` every scene of a `rbstudy.physics.scenes.SceneTable` has."""
    return {name for name, (has, _) in FEATURES.items() if has(scenes).all()}


# Per-case bookkeeping stored whatever `output.variables` says: the summary, the figures and
# the report read them (a few numbers per case).
BOOKKEEPING = ("status", "accuracy", "failure_time", "n_steps", "iterations", "run_time",
               "reference", "physical_body", "inertia", "initial_spin", "radioss_dt_limit")
# The reference's uncertainties (the variables of integrated references), kept whatever
# `output.variables` says wherever a study defines them: the order fits read them.
UNCERTAINTIES = tuple(name for name, variable in VARIABLES.items()
                      if "integrated" in variable.needs)


def selected(features):
    """Names of the variables a scene with ``features`` defines, in table order."""
    return [name for name, v in VARIABLES.items() if v.needs <= set(features)]


def evaluate(names, batch):
    """The values of the variables ``names`` for an `rbstudy.pipeline.outputs.BatchData`."""
    return {name: VARIABLES[name].compute(batch) for name in names}
