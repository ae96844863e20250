"""Memory layout of the per-body state and parameter rows: the only place that knows indices.

A batch of B bodies is two C-ordered float64 arrays, ``state`` (B, N_STATE) and ``params``
(B, N_PARAM), one row per body. A body's row is contiguous, so each thread of the batch driver
streams through its own body's data while it integrates all steps of that body.

State row (SI units):
    POSITION  3  centre-of-mass position in space (m)
    QUATERNION 4 orientation of the principal body frame, scalar-last (x, y, z, w); maps body
                 to space
    VELOCITY  3  centre-of-mass velocity in space (m/s)
    OMEGA     3  angular velocity in the principal body frame (rad/s)

Parameter row:
    MASS 1, INERTIA 3 (principal, kg m^2), FORCE_SPACE 3 (N), FORCE_BODY 3 (N, body axes),
    MOMENT_SPACE 3 (N m), MOMENT_BODY 3 (N m, body axes), GRAVITY 3 (m/s^2, space).
"""

__all__ = [
    "POSITION", "QUATERNION", "VELOCITY", "OMEGA", "N_STATE",
    "MASS", "INERTIA", "FORCE_SPACE", "FORCE_BODY", "MOMENT_SPACE", "MOMENT_BODY", "GRAVITY",
    "N_PARAM", "N_OPTION",
]

POSITION = 0
QUATERNION = 3
VELOCITY = 7
OMEGA = 10
N_STATE = 13

MASS = 0
INERTIA = 1
FORCE_SPACE = 4
FORCE_BODY = 7
MOMENT_SPACE = 10
MOMENT_BODY = 13
GRAVITY = 16
N_PARAM = 19

# Scheme options (e.g. HHT alpha, splitting axis order) travel per body in a row of this width,
# so that a batch may mix option values and a sweep over an option needs no recompilation.
N_OPTION = 4
