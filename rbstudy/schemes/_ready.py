"""Getting schemes ready before a sweep: compiled once per machine, in parallel the first time.

A scheme's entry point is compiled once per machine and loaded from numba's cache after
that (`rbstudy.numerics.entry`), at once. The first run after an install, or after a change
of rbstudy's sources, finds the cache empty and compiles every scheme the study needs, one
after the other on one core: numba compiles under the GIL. Those
compilations are independent, so `get_ready` hands them to child processes, one per core;
each child writes what it compiled into the cache, and this process then loads it.

The children are fresh interpreters (``python -c``), not `multiprocessing` workers, which
would import the caller's main script again (a script without a ``__main__`` guard would
run twice), and not forks of a process that may hold threads. Each takes the next scheme
nobody has claimed (a file created exclusively in a scratch folder), so the work balances
itself; a scheme's variants are compiled by one child, one after the other, because numba
rewrites a function's cache index without a lock.
"""

import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Collection
from typing import NamedTuple

import numba

from rbstudy.schemes._registry import Scheme

__all__ = ["get_ready", "Compiling"]

# A child: compile each scheme it is first to claim, every variant it is given.
_CHILD = """
import os, sys, time
from rbstudy.schemes._ready import DONE
from rbstudy.schemes import get_scheme
claims = sys.argv[1]
for item in sys.argv[2:]:
    name, _, variants = item.partition(":")
    try:
        os.close(os.open(os.path.join(claims, name), os.O_CREAT | os.O_EXCL))
    except FileExistsError:
        continue
    started = time.perf_counter()
    for variant in variants.split(","):
        get_scheme(name).ensure_compiled(timed=variant == "timed")
    took = str(time.perf_counter() - started).encode()
    done = os.open(os.path.join(claims, name + DONE + ".tmp"), os.O_CREAT | os.O_WRONLY)
    os.write(done, took)
    os.close(done)
    os.replace(os.path.join(claims, name + DONE + ".tmp"), os.path.join(claims, name + DONE))
"""
# The name a child gives a scheme's claim once the cache holds all its variants.
DONE = ".done"
# Seconds between two looks at the children's claims.
LOOK_SECONDS = 0.1


class Compiling(NamedTuple):
    """How the first run's compilation goes, as `get_ready` tells its ``watch``: the
    schemes the cache lacks (``total``), how many are done, those being compiled now, how
    many processes compile them, numba's cache folder, where they go, the names of the
    schemes the cache lacks and the seconds each done took to compile."""

    total: int
    done: int
    running: tuple
    processes: int
    cache: str
    names: tuple = ()  # the schemes the cache lacks
    took: tuple = ()  # (name, seconds) of each compiled so far


def get_ready(
    variants: Collection[tuple[Scheme, bool]],
    processes: int = 1,
    watch: Callable[[Compiling], object] | None = None,
) -> int:
    """Compile (or load from numba's cache) the schemes of ``variants``, pairs (`Scheme`,
    timed): ``timed`` asks for the variant that takes the time (loads tabulated in time,
    `rbstudy.numerics.clock`). When the cache lacks more than one scheme, up to
    ``processes`` child processes compile them first. Returns the number of variants the
    children put into the cache.

    ``watch(Compiling)``, when the cache lacks any scheme, is told before anything is
    compiled (done 0) and again whenever a scheme starts or ends: a first run is announced
    and shown, never silent.

    A child that fails (no memory, a broken interpreter) costs nothing but time: what it
    did not put into the cache, this process compiles itself. Ctrl-C ends the children.
    """
    schemes = {scheme.name: scheme for scheme, _ in variants}
    wanted = sorted({(scheme.name, timed) for scheme, timed in variants})
    cold: dict[str, list[bool]] = {}
    for name, timed in wanted:
        if not schemes[name].is_cached(timed):
            cold.setdefault(name, []).append(timed)
    processes = max(1, min(processes, len(cold)))
    tell = watch or (lambda compiling: None)
    # numba.config sets its options from the environment at import: its stubs name none
    cache = numba.config.CACHE_DIR  # type: ignore[attr-defined]
    names = tuple(cold)
    if cold:
        tell(Compiling(len(cold), 0, (), processes, cache, names))
    compiled, took = 0, {}
    if processes > 1:
        items = [
            f"{name}:{','.join('timed' if timed else 'plain' for timed in timings)}"
            for name, timings in cold.items()
        ]
        with tempfile.TemporaryDirectory(prefix="rbstudy-compile-") as claims:
            children = [
                subprocess.Popen(
                    [sys.executable, "-c", _CHILD, claims, *items],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    env={**os.environ, "PYTHONWARNINGS": "ignore"},
                )
                for _ in range(processes)
            ]
            try:
                took = _follow(children, claims, names, tell, cache)
            except BaseException:  # Ctrl-C: no child goes on compiling behind the user
                for child in children:
                    child.kill()
                raise
        compiled = sum(schemes[name].is_cached(timed) for name, timings in cold.items() for timed in timings)
    # what no child compiled, here
    here = [
        name
        for name, timings in cold.items()
        if processes == 1 or not all(schemes[name].is_cached(timed) for timed in timings)
    ]
    for count, name in enumerate(here):
        tell(
            Compiling(len(cold), len(cold) - len(here) + count, (name,), 1, cache, names, tuple(took.items()))
        )
        started = time.perf_counter()
        for timed in cold[name]:
            schemes[name].ensure_compiled(timed=timed)
        took[name] = time.perf_counter() - started
    for name, timed in wanted:  # loaded from the cache, in milliseconds
        schemes[name].ensure_compiled(timed=timed)
    if cold:
        tell(Compiling(len(cold), len(cold), (), processes, cache, names, tuple(took.items())))
    return compiled


def _follow(children, claims, names, tell, cache):
    """Wait for the compiling ``children``, telling ``tell`` what their ``claims`` show
    (a file per scheme claimed, another when it is done, holding the seconds it took) as
    it changes; the seconds of each scheme they compiled, name -> s."""
    said, took = (0, ()), {}  # as told before the children started
    while any(child.poll() is None for child in children):
        _took(claims, took)
        claimed = {name for name in os.listdir(claims) if not name.endswith((DONE, ".tmp"))}
        now = (len(took), tuple(sorted(claimed - set(took))))
        if now != said:
            said = now
            tell(Compiling(len(names), *now, len(children), cache, names, tuple(took.items())))
        time.sleep(LOOK_SECONDS)
    _took(claims, took)
    return took


def _took(claims, took):
    """Add to ``took`` the seconds of each scheme whose claim in ``claims`` is done."""
    for entry in os.listdir(claims):
        name = entry.removesuffix(DONE)
        if entry.endswith(DONE) and name not in took:
            try:
                with open(os.path.join(claims, entry), encoding="utf-8") as file:
                    took[name] = float(file.read())
            except (OSError, ValueError):  # unreadable: done, with no figure
                took[name] = math.nan
