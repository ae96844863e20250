"""The one place numba is configured.

`jit` compiles a kernel and caches it to disk, so that a second process starts without
compiling it; each scheme's batch entry point is such a kernel too (`rbstudy.numerics.entry`).
Kernels release the GIL (`nogil`): `rbstudy.numerics.driver` runs chunks of a batch on
several threads.
`error_model="numpy"` makes a division by zero give inf/nan instead of raising: numerical
failure must become a status code, never an exception (docs/architecture.md, numerics).
`fastmath` stays off: batch results must be bit-identical to single-case results, and the
energy-conserving schemes rely on IEEE semantics.

``jit(formula)`` also compiles a plain-Python formula of `rbstudy.numerics.algebra`, so that
kernels and numpy code share one written expression.

The cache lives in a folder named after a hash of this package's sources (`sources.py`). numba checks only
the timestamp of the file that defines a cached function, not of the files whose kernels it
inlines: after an edit of `algebra.py` alone, a cached scheme step would still run the old
formula. A new source tree gets a new, empty cache instead. The kernels of other packages
(plug-ins, docs/extending.md) get the same protection from a subfolder named after their
package's digest. ``NUMBA_CACHE_DIR``, when set, is respected as it is.
"""

import os
import threading
from typing import Any

import numba

from rbstudy.numerics.sources import SOURCE_DIGEST, package_digest

__all__ = ["jit", "inline_jit", "cache_dir"]


def cache_dir() -> str:
    """Numba's cache folder for this source tree.

    Returns
    -------
    str
        ``$XDG_CACHE_HOME/rbstudy/numba-<SOURCE_DIGEST>`` (~/.cache by default).
    """
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "rbstudy", f"numba-{SOURCE_DIGEST}")


# numba.config's attributes are set at run time, from the environment: its types do not list them
if not os.environ.get("NUMBA_CACHE_DIR"):
    numba.config.CACHE_DIR = cache_dir()  # type: ignore[attr-defined]

_COMMON: dict[str, Any] = dict(error_model="numpy", nogil=True)
# numba reads its cache folder when a function is decorated: `_cached` changes it meanwhile.
_FOLDER_LOCK = threading.Lock()
_digests: dict[str, str] = {}  # a plug-in package's digest, read once per process


def _cached(decorator):
    """``decorator``, with the kernels of other packages (plug-ins) cached in a folder named
    after a digest of their package's sources: numba checks only the file that defines a
    kernel, so a plug-in's edited helper module would otherwise leave its kernels' cache as
    it was, as rbstudy's own source digest prevents for rbstudy's kernels."""

    def decorate(function):
        package = function.__module__.split(".")[0]
        # rbstudy's own kernels and generated entry modules (whose names hold every digest)
        if package == "rbstudy" or package.startswith("rbstudy_entry_") or not numba.config.CACHE_DIR:
            return decorator(function)
        digest = _digests.get(package)
        if digest is None:
            try:
                digest = _digests[package] = package_digest(function.__module__)
            except ValueError:  # no source files to read (a script, a zipped install)
                return decorator(function)
        with _FOLDER_LOCK:
            folder = numba.config.CACHE_DIR
            numba.config.CACHE_DIR = os.path.join(folder, "plug-ins", f"{package}-{digest}")
            try:
                return decorator(function)
            finally:
                numba.config.CACHE_DIR = folder

    return decorate


jit = _cached(numba.njit(cache=True, **_COMMON))
# For a kernel on every scheme's hot path that has a rarely taken branch: numba inlines it
# into its callers before LLVM sees them. Left to LLVM, the loads' `body_moment` with its
# lever branch grew past LLVM's inlining threshold and was called instead, which cost the
# free body a fifth to a third of its steps per second; inlined, it runs nearly at its speed
# without loads at nodes (`pipelines/bench_loads.py` measures it).
inline_jit = _cached(numba.njit(cache=True, inline="always", **_COMMON))
