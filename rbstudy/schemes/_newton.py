"""Settings shared by the Newton solvers of the implicit schemes (midpoint, hht)."""

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
