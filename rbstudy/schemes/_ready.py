"""Getting schemes ready before a sweep: compiled once per machine, in parallel the first time.

A scheme's entry point is compiled once per machine and loaded from numba's cache after
that (`rbstudy.numerics.entry`), in milliseconds. The first run after an install, or after
a change of rbstudy's sources, finds the cache empty and compiles every scheme the study
needs, 1-3 s each and 16 s for all ten, on one core: numba compiles under the GIL. Those
compilations are independent, so `get_ready` hands them to child processes, one per core;
each child writes what it compiled into the cache, and this process then loads it. Children
are spawned, not forked: the parent may hold threads and an initialised LLVM.
"""

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

__all__ = ["get_ready"]


def _compile(name, timed):
    """In a child process: compile the variant ``timed`` of scheme ``name`` into the cache."""
    from rbstudy.schemes import get_scheme

    get_scheme(name).ensure_compiled(timed=timed)


def get_ready(variants, processes=1):
    """Compile (or load from numba's cache) the schemes of ``variants``, pairs (name, timed):
    ``timed`` asks for the variant that takes the time (loads tabulated in time,
    `rbstudy.numerics.clock`). Variants the cache lacks are first compiled in up to
    ``processes`` child processes, when that is more than one of each. Returns the number of
    variants compiled in children.

    A child that fails (no way to start processes, too little memory) costs nothing but
    time: whatever it did not put into the cache, this process compiles itself.
    """
    from rbstudy.schemes import get_scheme

    variants = sorted(set(variants))
    cold = [(name, timed) for name, timed in variants
            if not get_scheme(name).is_cached(timed)]
    if processes > 1 and len(cold) > 1:
        try:
            with ProcessPoolExecutor(min(processes, len(cold)),
                                     mp_context=multiprocessing.get_context("spawn")) as pool:
                list(pool.map(_compile, *zip(*cold, strict=True)))
        except Exception:  # noqa: BLE001 (compiled below instead: slower, not wrong)
            cold = []
    else:
        cold = []
    for name, timed in variants:
        get_scheme(name).ensure_compiled(timed=timed)
    return len(cold)
