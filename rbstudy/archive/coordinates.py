"""The metadata of what an archive holds beside its output variables: the coordinates (the
output grid and the named sweep axes), the step search's own variables, what is recorded of
each scheme, and the units of a value swept by dotted path, in CF attributes (`cf_attrs`).

The output variables themselves are the one table of `rbstudy.archive.variables`.
"""

__all__ = [
    "TIME_UNITS",
    "COORDINATES",
    "SEARCH_VARIABLES",
    "SCHEME_COORDINATES",
    "coordinate_units",
    "cf_attrs",
]

# Simulated time is a duration, not a date: plain seconds, which every reader (xarray
# included) opens as numbers. (A "seconds since <epoch>" unit made xarray decode it to
# calendar dates.)
TIME_UNITS = "s"

# Coordinates: the output grid and the named sweep axes. (units, long_name); units None for
# labels.
COORDINATES: dict[str, tuple[str | None, str]] = {
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

# The step search's own variables (`sweep --find-step`, the archive's group `search`), beside
# what a probe shares with a case: (units, long_name), as `COORDINATES`.
SEARCH_VARIABLES: dict[str, tuple[str | None, str]] = {
    "case": (None, "grid case whose scene and scheme options the probe runs (C order of the sweep)"),
    "steps": ("1", "time steps over the duration"),
    "output_interval": ("s", "interval of the samples the verdict is taken at"),
    "group_scheme": (None, "scheme of the group (a scheme at one value of every other swept axis)"),
    "group_case": (None, "a grid case of the group: its scene and scheme options"),
    "grid_dt": ("s", "largest swept step meeting the accuracy bound"),
    "found_dt": ("s", "largest step found to meet the accuracy bound"),
    "failing_dt": ("s", "smallest step found above it that does not (NaN: none up to the duration)"),
    "found_seconds": ("s", "calibrated kernel seconds of the group's case at its found step"),
    "study_scheme": (None, "scheme met the bound at one step at every value of the other axes"),
    "study_dt": ("s", "its least found step, met at every value of the other axes"),
    "study_seconds": ("s", "mean calibrated kernel seconds a case at that step"),
    "study_uncertainty": ("1", "relative uncertainty of those seconds (the calibration's)"),
}

# What the archive records of each scheme, beside the `scheme` coordinate, so that the
# summary, figures and report never need the registry (nor a compiler): name ->
# (Scheme attribute, units, long_name).
SCHEME_COORDINATES: dict[str, tuple[str, str | None, str]] = {
    "nominal_order": ("order", "1", "nominal global order of accuracy of the scheme"),
    "claimed_invariants": ("keeps", None, "invariants kept to round-off by a moment-free body"),
    "scheme_origin": ("origin", None, "provider of the scheme: rbstudy, or a package and version"),
}

# Units of a value swept by dotted path, found from the last key of the path that is listed
# here (``scene.initial.angular_velocity.body.2`` -> ``body`` under ``angular_velocity``). A
# scheme option's come from the option (`rbstudy.schemes.Option.units`).
_KEY_UNITS = {
    "mass": "kg",
    "inertia": "kg m2",
    "angular_velocity": "rad s-1",
    "position": "m",
    "velocity": "m s-1",
    "euler_zxz_deg": "degree",
    "phi_deg": "degree",
    "quaternion": "1",
    "rotation_vector": "rad",
    "momentum_axis": "1",
    "nodes": "m",
    "force_space": "N",
    "force_body": "N",
    "moment_space": "N m",
    "moment_body": "N m",
    "gravity": "m s-2",
}


def coordinate_units(target: str) -> str | None:
    """Units of the values of a sweep axis (short name or dotted path), None if a label."""
    if target in COORDINATES:
        return COORDINATES[target][0]
    for key in reversed(target.split(".")):
        if key in _KEY_UNITS:
            return _KEY_UNITS[key]
    return None


def cf_attrs(units: str | None, long_name: str) -> dict[str, str]:
    """CF ``long_name`` and, for a quantity with units, ``units``."""
    return {"long_name": long_name} | ({"units": units} if units else {})
