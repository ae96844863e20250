"""The one place numba is configured.

`jit` compiles a kernel and caches it to disk, so that a second process starts without
compiling it. `entry_jit` compiles a scheme's batch entry point, which numba (0.6x) cannot
cache because it calls the generic driver with the scheme's kernels as arguments ("dynamic
globals"); it is compiled once per process, 1-2 s per scheme (docs/performance.md). Kernels
release the GIL (`nogil`): `rbstudy.driver` runs chunks of a batch on several threads.
`error_model="numpy"` makes a division by zero give inf/nan instead of raising: numerical
failure must become a status code, never an exception (design.md, numerics layer).
`fastmath` stays off: batch results must be bit-identical to single-case results, and the
energy-conserving schemes rely on IEEE semantics.
"""

import numba

__all__ = ["jit", "entry_jit"]

_COMMON = dict(error_model="numpy", nogil=True)

jit = numba.njit(cache=True, **_COMMON)
entry_jit = numba.njit(cache=False, **_COMMON)
