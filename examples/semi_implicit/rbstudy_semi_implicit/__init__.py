"""An example rbstudy plug-in: the semi-implicit Euler step of game and robotics engines.

One step of size h, with w the body angular velocity, I the principal inertias, M the body
moment, F the force in space (the scheme's formula, written once for both files):

    (I + h ([w]x I - [I w]x)) dw = h (M - w x I w)    the gyroscopic term linearised-
    w+ = w + dw                                       implicit in the body frame
    v+ = v + h F / mass
    x+ = x + h v+,   q+ = q * exp(h w+ / 2)           positions with the new velocities

Velocities first, then positions with the new velocities: symplectic Euler for the
translation. The rotation solves backward Euler for the gyroscopic term with one Newton
step from w (Bullet's "implicit gyroscopic force in the body frame"; engines do it so that a
fast-spinning thin body does not gain energy). Order 1; it keeps no invariant.

- `compiled`: the fast kind, single-body kernels compiled with numba (`semi_implicit`).
- `vectorised`: the same step in numpy over a batch of bodies (`semi_implicit_numpy`), the
  kind that wraps foreign code; its numbers agree with the compiled one's to round-off.
"""
