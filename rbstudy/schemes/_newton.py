"""What the Newton solvers of the implicit schemes (midpoint, hht) share: their settings, the
test after each pass (`newton_test`, both paths) and a block lane's record of it
(`book_newton_pass`: hht's; midpoint's loop, which vectorises, books its own lanes)."""

import math

from rbstudy.numerics import block as B
from rbstudy.numerics.jit import inline_jit

# Stop when the Newton correction is below this fraction of the unknown's scale: a few ulps,
# so a converged step is exact to round-off and the midpoint rule keeps energy to ~1e-15.
NEWTON_RTOL = 4e-15

# Iterations before a step is declared NOT_CONVERGED. Newton converges quadratically from the
# explicit predictor in 2-4 iterations while h |w| < ~2; needing more means the step is too big.
NEWTON_MAX_ITERATIONS = 30

# For a residual-based test (hht): the equilibrium residual is a sum of terms of size ``scale``
# that cancel, so its floor is a few ulps of ``scale``; 1e-12 sits safely above that floor and
# far below any truncation error of the step.
NEWTON_RESIDUAL_RTOL = 1e-12


@inline_jit
def newton_test(iterating, size, bound, iterations):
    """The test after a Newton pass, for one body or one lane of a block.

    Parameters
    ----------
    iterating : bool
        Whether the body still iterates (a block's lane may have stopped).
    size : float
        The size the scheme tests (a residual's, a correction's).
    bound : float
        Converged at ``size <= bound``.
    iterations : int or float
        The iterations counted with this pass.

    Returns
    -------
    converged, update, going_on : bool
        Converged (finite and within ``bound``); to be updated (finite, not converged); and
        updated with iterations left (fewer than NEWTON_MAX_ITERATIONS).
    """
    finite = iterating & math.isfinite(size)
    converged = finite & (size <= bound)
    update = finite & (not converged)
    going_on = update & (iterations < NEWTON_MAX_ITERATIONS)
    return converged, update, going_on


@inline_jit
def book_newton_pass(block, rows, lane, converged, going_on, iterations):
    """Record a block lane's `newton_test` in the rows of `rbstudy.numerics.block.start_newton`
    from ``rows``: whether it iterates on, whether it converged (kept once it has), its
    iterations. Returns 1 when it iterates on, else 0 (inlined, so that ``rows`` stays a
    constant and the caller's loop over lanes vectorises)."""
    block[rows * B.BLOCK + lane] = 1.0 if going_on else 0.0
    block[(rows + 1) * B.BLOCK + lane] = 1.0 if converged else B.at(block, rows + 1, lane)
    block[(rows + 2) * B.BLOCK + lane] = iterations
    return 1 if going_on else 0
