"""The one table of output variables: dimensions, units, CF names, and when each exists.

Every variable the archive can hold is described here once; the store reads its ``units``,
``long_name`` and ``standard_name`` attributes from this table and nowhere else. ``needs``
names the scene features a variable requires, so that a variable a scene does not define is
left out instead of filled with NaN:

- ``nodes``: the scene has nodes fixed to the body;
- ``translation``: the centre of mass moves;
- ``reference``: a reference solution (closed form, or DOP853 where none exists);
- ``symmetric``: a moment-free symmetric body (precession frequency);
- ``moment_free``: energy and angular momentum are conserved, so their drift is an error.
"""

from dataclasses import dataclass

__all__ = ["Variable", "VARIABLES", "STATUS_FLAGS", "selected"]


@dataclass(frozen=True)
class Variable:
    name: str
    dims: tuple  # beyond the case dimensions
    units: str
    long_name: str
    needs: frozenset = frozenset()
    standard_name: str | None = None


def _v(name, dims, units, long_name, *needs, standard_name=None):
    return Variable(name, dims, units, long_name, frozenset(needs), standard_name)


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
    _v("status", (), "1", "case outcome"),
    _v("failure_time", (), "s", "time of blow-up or solver failure (NaN if none)"),
    _v("n_steps", (), "1", "time steps taken"),
    _v("iterations", (), "1", "Newton iterations summed over the steps"),
    _v("run_time", (), "s", "kernel wall time per case: batch time / batch size, after compilation"),
    _v("max_energy_error", (), "1", "largest |relative energy error| over every step",
       "moment_free"),
    _v("max_momentum_error", (), "1", "largest relative |L| drift over every step", "moment_free"),
    _v("final_orientation_error", (), "rad", "orientation error at the last output time",
       "reference"),
)}

# CF flags of `status` (values match rbstudy.driver's codes).
STATUS_FLAGS = {"flag_values": [0, 1, 2], "flag_meanings": "ok unstable not_converged"}


def selected(features, requested=None):
    """Names of the variables a scene with ``features`` defines, in table order.

    ``requested`` (optional) narrows the choice; asking for a variable the scene cannot
    define raises ``KeyError`` naming it.
    """
    available = [name for name, v in VARIABLES.items() if v.needs <= set(features)]
    if requested is None:
        return available
    missing = [name for name in requested if name not in available]
    if missing:
        raise KeyError(", ".join(missing))
    return [name for name in available if name in requested]
