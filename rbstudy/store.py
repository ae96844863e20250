"""Results on disk: CF-1.11 netCDF datasets built from the variable table, written atomically.

This first version stores one case per study (no swept dimensions yet); the dimension and
variable names are the public contract of issue 3: ``time``, ``node``, ``axis`` (x, y, z),
``component`` (x, y, z, w), and the variables of `rbstudy.variables`.
"""

import datetime
import os
import pathlib
import platform
import sys
import tempfile
from importlib import metadata

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from rbstudy.analytic import precession_frequency_exact
from rbstudy.errors import RbstudyError
from rbstudy.metrics import (
    energy_error,
    momentum_error,
    node_positions,
    omega_error,
    orientation_error,
    phase_rate,
)
from rbstudy.variables import STATUS_FLAGS, VARIABLES, selected

__all__ = ["case_dataset", "write_atomic", "scene_features"]

_DEPENDENCIES = ("numpy", "scipy", "numba", "xarray", "netCDF4", "dask", "matplotlib", "PyYAML")


def scene_features(scene):
    """The features of `rbstudy.variables` that ``scene`` has."""
    features = {"reference"}
    if len(scene.nodes):
        features.add("nodes")
    if scene.translates:
        features.add("translation")
    if scene.loads.moment_free:
        features.add("moment_free")
        if scene.body.symmetry_axis is not None:
            features.add("symmetric")
    return features


def _versions():
    found = {}
    for name in ("rbstudy",) + _DEPENDENCIES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def case_dataset(study, run, reference):
    """The dataset of one case: ``run`` a one-body `Simulation`, ``reference`` a `Reference`."""
    scene = study.scene
    inertia = np.array(scene.body.inertia)
    quaternion, omega = run.quaternion[0], run.omega_body[0]
    finite = np.all(np.isfinite(quaternion), axis=-1)
    omega_space = np.full_like(omega, np.nan)
    omega_space[finite] = Rotation.from_quat(quaternion[finite]).apply(omega[finite])
    values = {
        "omega_body": omega,
        "omega_space": omega_space,
        "quaternion": quaternion,
        "position": run.position[0],
        "energy_error": energy_error(omega, inertia),
        "momentum_error": momentum_error(quaternion, omega, inertia),
        "orientation_error": orientation_error(quaternion, reference.quaternion),
        "omega_error": omega_error(omega, reference.omega_body),
        "status": run.status[0],
        "failure_time": run.failure_time[0],
        "n_steps": run.n_steps[0],
        "iterations": run.iterations[0],
        "run_time": run.kernel_seconds,
        "max_energy_error": run.max_energy_drift[0],
        "max_momentum_error": run.max_momentum_drift[0],
    }
    values["final_orientation_error"] = values["orientation_error"][-1]
    if len(scene.nodes):
        safe = np.where(finite[:, None], quaternion, [0.0, 0.0, 0.0, 1.0])
        nodes = node_positions(safe, run.position[0], scene.nodes)
        nodes[~finite] = np.nan
        nodes_ref = node_positions(reference.quaternion, reference.position, scene.nodes)
        values["node_displacement"] = nodes - nodes[:1]
        values["node_error"] = np.linalg.norm(nodes - nodes_ref, axis=-1)
    exact = precession_frequency_exact(scene)
    if exact is not None:
        axis = scene.body.symmetry_axis
        a, b = omega[:, (axis + 1) % 3], omega[:, (axis + 2) % 3]
        measured = float(phase_rate(a, b, run.time))
        values.update(precession_frequency=measured, precession_frequency_exact=exact,
                      precession_frequency_error=measured - exact)

    names = selected(scene_features(scene))
    data_vars = {}
    for name in names:
        variable = VARIABLES[name]
        attrs = {"units": variable.units, "long_name": variable.long_name}
        if variable.standard_name:
            attrs["standard_name"] = variable.standard_name
        if name == "status":
            attrs = {"long_name": variable.long_name, **STATUS_FLAGS}
        if variable.needs & {"reference"}:
            attrs["reference"] = reference.name
        data_vars[name] = (variable.dims, np.asarray(values[name]), attrs)
    coords = {
        "time": ("time", run.time, {"units": "s", "long_name": "time", "standard_name": "time",
                                    "axis": "T"}),
        "axis": ("axis", np.array(["x", "y", "z"]), {"long_name": "vector component"}),
        "component": ("component", np.array(["x", "y", "z", "w"]),
                      {"long_name": "quaternion component, scalar last"}),
    }
    if len(scene.nodes):
        coords["node"] = ("node", np.array(scene.node_names), {"long_name": "node name"})
    now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    versions = _versions()
    attrs = {
        "Conventions": "CF-1.11",
        "title": study.title,
        "source": f"rbstudy {versions['rbstudy']}",
        "history": f"{now} {' '.join(sys.argv) or 'rbstudy'}",
        "study": study.name,
        "scheme": study.scheme,
        "dt": study.dt,
        "reference": reference.name,
        "physical_body": int(scene.body.physical),
        "config": study.text,
        "platform": platform.platform(),
        "versions": "; ".join(f"{k} {v}" for k, v in versions.items()),
    }
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def write_atomic(dataset, path):
    """Write ``dataset`` to ``path`` through a temporary file in the same folder, then rename,
    so that a reader never sees a half-written file."""
    path = pathlib.Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                                             suffix=".tmp")
        os.close(handle)
    except OSError as error:
        raise RbstudyError(f"{path.parent}: cannot write results there ({error.strerror}); "
                           "choose another folder with --out") from None
    try:
        dataset.to_netcdf(temporary)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)
