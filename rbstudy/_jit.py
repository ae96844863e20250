"""The one place numba is configured.

`jit` compiles a kernel and caches it to disk, so that a second process starts without
compiling it. `entry_jit` is for functions that take kernels as arguments (the generic
driver loop) or pass them (each scheme's batch entry point): numba cannot cache those
safely, so they compile once per process, under a second per scheme (docs/performance.md). Kernels
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
