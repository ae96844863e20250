"""What a package needs to add its own schemes to rbstudy: one import (docs/extending.md).

    from rbstudy.extending import Scheme, jit, make_entry, state as S, rotation, dynamics

- `Scheme`, `Option`, `Style`: a scheme as the registry sees it, and how the figures draw
  its lines; register it under the entry-point group ``rbstudy.schemes``. `option_slots`:
  where the registry lays out your options in the option row, for your kernels to read.
  `SchemeUnavailable`: raise it from your module when the scheme cannot run here (a missing
  engine), with the fix.
- A compiled scheme: single-body kernels ``init(y, p, opt, t, h, work) -> status`` and
  ``step(y, p, opt, t, h, work) -> (status, iterations)`` compiled with `jit`, given their
  entry point by `make_entry(step, init, n_work)`; `init_nothing` is the ``init`` of a
  scheme that carries nothing between steps. `rotation` and `dynamics` hold the scalar
  kernels rbstudy's own schemes are written with (quaternions, loads, Euler's equations);
  `later(t, d)` is the time of a stage ``d`` into a step that starts at ``t``.
- A vectorised scheme: the same two functions over arrays of bodies, in numpy, given their
  entry point by `make_batch_entry(step, init, n_work)`; `batch_loads` gives them every
  load a scene can carry (force in space, moment in the body frame), and `algebra` the
  formulas rbstudy writes once for scalars and arrays alike (the Hamilton product, the
  rotation's columns, the invariants).
- `state`: the layout of the state, parameter and option rows, and the status codes.

This module is the contract: what it names keeps its meaning between releases.
"""

from rbstudy.numerics import algebra, dynamics, rotation, state
from rbstudy.numerics.batch_driver import batch_loads, make_batch_entry
from rbstudy.numerics.clock import later
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.entry import make_entry
from rbstudy.numerics.jit import jit
from rbstudy.numerics.state import NOT_CONVERGED, OK, UNSTABLE
from rbstudy.schemes import Option, Scheme, SchemeUnavailable, Style, option_slots

__all__ = [
    "Scheme",
    "Option",
    "Style",
    "option_slots",
    "SchemeUnavailable",
    "jit",
    "make_entry",
    "init_nothing",
    "make_batch_entry",
    "batch_loads",
    "later",
    "algebra",
    "state",
    "rotation",
    "dynamics",
    "OK",
    "UNSTABLE",
    "NOT_CONVERGED",
]
