"""The one place numba is configured.

`jit` compiles a kernel and caches it to disk, so that a second process starts without
compiling. Kernels release the GIL (`nogil`): `rbstudy.driver` runs chunks of a batch on
several threads.
`error_model="numpy"` makes a division by zero give inf/nan instead of raising: numerical
failure must become a status code, never an exception (design.md, numerics layer).
`fastmath` stays off: batch results must be bit-identical to single-case results, and the
energy-conserving schemes rely on IEEE semantics.
"""

import numba

__all__ = ["jit"]

_COMMON = dict(cache=True, error_model="numpy", nogil=True)

jit = numba.njit(**_COMMON)
