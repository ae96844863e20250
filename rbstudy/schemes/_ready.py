"""Getting schemes ready before a sweep: compiled once per machine, in parallel the first time.

A scheme's entry point is compiled once per machine and loaded from numba's cache after
that (`rbstudy.numerics.entry`), in milliseconds. The first run after an install, or after
a change of rbstudy's sources, finds the cache empty and compiles every scheme the study
needs, 1-3 s each and 16 s for all ten, on one core: numba compiles under the GIL. Those
compilations are independent, so `get_ready` hands them to child processes, one per core;
each child writes what it compiled into the cache, and this process then loads it.

The children are fresh interpreters (``python -c``), not `multiprocessing` workers, which
would import the caller's main script again (a script without a ``__main__`` guard would
run twice), and not forks of a process that may hold threads. Each takes the next scheme
nobody has claimed (a file created exclusively in a scratch folder), so the work balances
itself; a scheme's variants are compiled by one child, one after the other, because numba
rewrites a function's cache index without a lock.
"""

import os
import subprocess
import sys
import tempfile

__all__ = ["get_ready"]

# A child: compile each scheme it is first to claim, every variant it is given.
_CHILD = """
import os, sys
from rbstudy.schemes import get_scheme
claims = sys.argv[1]
for item in sys.argv[2:]:
    name, _, variants = item.partition(":")
    try:
        os.close(os.open(os.path.join(claims, name), os.O_CREAT | os.O_EXCL))
    except FileExistsError:
        continue
    for variant in variants.split(","):
        get_scheme(name).ensure_compiled(timed=variant == "timed")
"""


def get_ready(variants, processes=1):
    """Compile (or load from numba's cache) the schemes of ``variants``, pairs (name, timed):
    ``timed`` asks for the variant that takes the time (loads tabulated in time,
    `rbstudy.numerics.clock`). When the cache lacks more than one scheme, up to
    ``processes`` child processes compile them first. Returns the number of variants the
    children put into the cache.

    A child that fails (no memory, a broken interpreter) costs nothing but time: what it
    did not put into the cache, this process compiles itself. Ctrl-C ends the children.
    """
    from rbstudy.schemes import get_scheme

    variants = sorted(set(variants))
    cold = {}
    for name, timed in variants:
        if not get_scheme(name).is_cached(timed):
            cold.setdefault(name, []).append(timed)
    compiled = 0
    if processes > 1 and len(cold) > 1:
        items = [f"{name}:{','.join('timed' if timed else 'plain' for timed in timings)}"
                 for name, timings in cold.items()]
        with tempfile.TemporaryDirectory(prefix="rbstudy-compile-") as claims:
            children = [subprocess.Popen([sys.executable, "-c", _CHILD, claims, *items],
                                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                         env={**os.environ, "PYTHONWARNINGS": "ignore"})
                        for _ in range(min(processes, len(cold)))]
            try:
                for child in children:
                    child.wait()
            except BaseException:  # Ctrl-C: no child goes on compiling behind the user
                for child in children:
                    child.kill()
                raise
        compiled = sum(get_scheme(name).is_cached(timed)
                       for name, timings in cold.items() for timed in timings)
    for name, timed in variants:
        get_scheme(name).ensure_compiled(timed=timed)
    return compiled
