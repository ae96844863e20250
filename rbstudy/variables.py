"""The one table of output variables: dimensions, units, CF names, and when each exists.

Every variable the archive can hold is described here once; the store reads its ``units``,
``long_name`` and ``standard_name`` attributes from this table and nowhere else. ``needs``
names the scene features a variable requires, so that a variable a scene does not define is
left out instead of filled with NaN:

- ``nodes``: the scene has nodes fixed to the body;
- ``translation``: the centre of mass moves;
- ``reference``: a reference solution (closed form, or DOP853 where none exists);
- ``symmetric``: a moment-free symmetric body (precession frequency);
- ``moment_free``: energy and angular momentum are conserved, so their drift is an error;
- ``asymmetric``: a moment-free body with three different inertias (flip interval).
"""

from dataclasses import dataclass

__all__ = ["Variable", "VARIABLES", "STATUS_FLAGS", "REFERENCE_FLAGS", "COORDINATES", "TIME_UNITS",
           "coordinate_units", "variable_attrs", "scene_features", "selected", "BOOKKEEPING"]


@dataclass(frozen=True)
class Variable:
    name: str
    dims: tuple  # beyond the case dimensions
    units: str
    long_name: str
    needs: frozenset = frozenset()
    standard_name: str | None = None
    dtype: str = "f8"  # netCDF storage type: flags are bytes, counts 64-bit integers


def _v(name, dims, units, long_name, *needs, standard_name=None, dtype="f8"):
    return Variable(name, dims, units, long_name, frozenset(needs), standard_name, dtype)


VARIABLES = {v.name: v for v in (
    _v("omega_body", ("time", "axis"), "rad s-1", "angular velocity in principal body axes"),
    _v("omega_space", ("time", "axis"), "rad s-1", "angular velocity in space axes"),
    _v("quaternion", ("time", "component"), "1",
       "orientation quaternion, scalar-last (x, y, z, w), principal body axes to space"),
    _v("position", ("time", "axis"), "m", "centre-of-mass position", "translation"),
    _v("node_displacement", ("time", "node", "axis"), "m", "displacement of nodes fixed to the body",
       "nodes"),
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
    _v("status", (), "1", "case outcome", dtype="i1"),
    _v("failure_time", (), "s", "time of blow-up or solver failure (NaN if none)"),
    _v("n_steps", (), "1", "time steps taken", dtype="i8"),
    _v("iterations", (), "1", "Newton iterations summed over the steps", dtype="i8"),
    _v("run_time", (), "s", "kernel CPU time per case: CPU time of the compiled batch call, "
       "summed over its threads, / batch size; compilation excluded"),
    _v("max_energy_error", (), "1", "largest |relative energy error| over every step",
       "moment_free"),
    _v("max_momentum_error", (), "1",
       "largest relative drift of the magnitude |L| over every step (the vector's drift, "
       "sampled, is momentum_error)", "moment_free"),
    _v("final_orientation_error", (), "rad", "orientation error at the last output time",
       "reference"),
    _v("reference", (), "1", "reference solution the errors are measured against", "reference",
       dtype="i1"),
    _v("inertia", ("axis",), "kg m2", "principal moments of inertia"),
    _v("initial_spin", (), "rad s-1", "initial angular speed |w(0)|"),
    _v("node_offset", ("node", "axis"), "m", "node offsets from the centre of mass, principal axes",
       "nodes"),
    _v("physical_body", (), "1",
       "whether the principal inertias meet the triangle inequality (a real rigid body)",
       dtype="i1"),
)}

# CF flags of `status` (values match rbstudy.driver's codes) and of `reference` (names match
# rbstudy.analytic's `Reference.name`).
STATUS_FLAGS = {"flag_values": [0, 1, 2], "flag_meanings": "ok unstable not_converged"}
REFERENCE_FLAGS = {"flag_values": [0, 1, 2],
                   "flag_meanings": "symmetric_top axial_moment dop853"}
PHYSICAL_FLAGS = {"flag_values": [0, 1], "flag_meanings": "unphysical_stress_body physical"}
_FLAGS = {"status": STATUS_FLAGS, "reference": REFERENCE_FLAGS, "physical_body": PHYSICAL_FLAGS}

# CF-1.11 requires a reference epoch on a time coordinate. The epoch stands for t = 0 of the
# run, not a calendar date: open results with ``decode_times=False`` (as
# `rbstudy.store.open_results` does) to read seconds.
TIME_UNITS = "seconds since 1970-01-01 00:00:00"

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


def variable_attrs(name):
    """The CF attributes of output variable ``name``, all from the table above."""
    variable = VARIABLES[name]
    if name in _FLAGS:
        return {"long_name": variable.long_name, **_FLAGS[name]}
    attrs = {"units": variable.units, "long_name": variable.long_name}
    if variable.standard_name:
        attrs["standard_name"] = variable.standard_name
    return attrs


def scene_features(scene):
    """The features (see the module docstring) that a `rbstudy.scenes.Scene` has."""
    features = {"reference"}
    if len(scene.nodes):
        features.add("nodes")
    if scene.translates:
        features.add("translation")
    if scene.loads.moment_free:
        features.add("moment_free")
        if scene.body.symmetry_axis is not None:
            features.add("symmetric")
        elif len(set(scene.body.inertia)) == 3:
            features.add("asymmetric")
    return features


# Per-case bookkeeping stored whatever `output.variables` says: the summary, the figures and
# the report read them (a few numbers per case).
BOOKKEEPING = ("status", "failure_time", "n_steps", "iterations", "run_time", "reference",
               "physical_body", "inertia", "initial_spin")


def selected(features):
    """Names of the variables a scene with ``features`` defines, in table order."""
    return [name for name, v in VARIABLES.items() if v.needs <= set(features)]
