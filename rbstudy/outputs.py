"""The named outputs of a batch: a `Simulation` and its references -> the variables of the table.

Everything a case stores is computed here, vectorised over the batch where the bodies share
shapes, from the sampled states, the scenes and the references (`rbstudy.analytic`). Samples
after a blow-up are NaN; every measure taken from them is NaN too.
"""

import numpy as np

from rbstudy.analytic import flip_interval_exact, precession_frequency_exact
from rbstudy.metrics import (
    energy_error,
    momentum_error,
    node_positions,
    omega_error,
    orientation_error,
    phase_rate,
    sign_change_interval,
)
from rbstudy.quaternions import quat_to_matrix
from rbstudy.variables import REFERENCE_FLAGS

__all__ = ["batch_outputs", "REFERENCE_CODES"]

REFERENCE_CODES = {name: code for code, name in zip(REFERENCE_FLAGS["flag_values"],
                                                     REFERENCE_FLAGS["flag_meanings"].split(), strict=True)}
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def _transverse(omega, scenes):
    """The two transverse components (B, T) each of the body rates ``omega`` (B, T, 3) of
    symmetric bodies, in cyclic order after each body's symmetry axis."""
    axes = np.array([scene.body.symmetry_axis for scene in scenes])[:, None, None]
    first = np.take_along_axis(omega, (axes + 1) % 3, axis=2)[..., 0]
    second = np.take_along_axis(omega, (axes + 2) % 3, axis=2)[..., 0]
    return first, second


def batch_outputs(scenes, run, references, names, run_time):
    """The values of the variables ``names`` for the B cases of a batch.

    Parameters
    ----------
    scenes : (B,) `rbstudy.scenes.Scene`.
    run : `rbstudy.simulate.Simulation` of those scenes, T samples.
    references : (B,) `rbstudy.analytic.Reference` on the same T times.
    names : variable names of `rbstudy.variables.VARIABLES` to compute.
    run_time : (B,) s, kernel time per case.

    Returns a mapping name -> array with the batch axis first: (B, T, 3) for vectors over time,
    (B, T, N, 3) for nodes, (B,) per case.
    """
    names = set(names)
    q, w = run.quaternion, run.omega_body
    finite = np.all(np.isfinite(q), axis=-1)  # (B, T)
    safe_q = np.where(finite[..., None], q, _IDENTITY)
    inertia = np.array([scene.body.inertia for scene in scenes])[:, None, :]  # (B, 1, 3)
    values = {
        "omega_body": w,
        "quaternion": q,
        "position": run.position,
        "status": run.status,
        "failure_time": run.failure_time,
        "n_steps": run.n_steps,
        "iterations": run.iterations,
        "run_time": np.asarray(run_time, dtype=float),
        "max_energy_error": run.max_energy_drift,
        "max_momentum_error": run.max_momentum_drift,
        "physical_body": np.array([scene.body.physical for scene in scenes], dtype=np.int8),
        "inertia": inertia[:, 0, :],
        "initial_spin": np.linalg.norm(w[:, 0], axis=-1),
    }
    if "omega_space" in names:
        space = np.einsum("btij,btj->bti", quat_to_matrix(safe_q), w)
        values["omega_space"] = np.where(finite[..., None], space, np.nan)
    if "energy_error" in names:
        values["energy_error"] = energy_error(w, inertia)
    if "momentum_error" in names:
        values["momentum_error"] = momentum_error(q, w, inertia)
    if names & {"orientation_error", "final_orientation_error", "omega_error", "reference"}:
        q_ref = np.array([ref.quaternion for ref in references])
        values["orientation_error"] = orientation_error(q, q_ref)
        values["final_orientation_error"] = values["orientation_error"][:, -1]
        values["omega_error"] = omega_error(w, np.array([ref.omega_body for ref in references]))
        values["reference"] = np.array([REFERENCE_CODES[ref.name] for ref in references],
                                       dtype=np.int8)
    if names & {"node_displacement", "node_error", "node_offset"}:
        offsets = np.array([scene.nodes for scene in scenes])  # (B, N, 3)
        values["node_offset"] = offsets
        nodes = node_positions(safe_q, run.position, offsets)  # (B, T, N, 3)
        nodes[~finite] = np.nan
        values["node_displacement"] = nodes - nodes[:, :1]
        if "node_error" in names:
            exact = node_positions(np.array([ref.quaternion for ref in references]),
                                   np.array([ref.position for ref in references]), offsets)
            values["node_error"] = np.linalg.norm(nodes - exact, axis=-1)
    if names & {"precession_frequency", "precession_frequency_exact",
                "precession_frequency_error"}:
        measured = phase_rate(*_transverse(w, scenes), run.time)
        exact = np.array([precession_frequency_exact(scene) for scene in scenes])
        values["precession_frequency"] = measured
        values["precession_frequency_exact"] = exact
        values["precession_frequency_error"] = measured - exact
    if names & {"flip_interval", "flip_interval_exact", "flip_interval_error"}:
        middle = [int(np.argsort(scene.body.inertia)[1]) for scene in scenes]
        measured = np.array([sign_change_interval(w[b, :, axis], run.time)
                             for b, axis in enumerate(middle)])
        exact = np.array([flip_interval_exact(scene) for scene in scenes])
        values.update(flip_interval=measured, flip_interval_exact=exact,
                      flip_interval_error=measured - exact)
    return {name: values[name] for name in names}
