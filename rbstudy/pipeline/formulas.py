"""Each output variable bound to the function that computes it from a batch.

The table of variables (`rbstudy.archive.variables.VARIABLES`) is metadata only; the
functions live in `rbstudy.pipeline.outputs`, one per variable and of the same name, or are
the driver's per-body results (`rbstudy.numerics.state.RESULT_FIELDS`); those of the
reference live in `rbstudy.pipeline.reference_outputs`. A deprecated alias
computes as the name that replaced it. `FORMULAS` is bound at import, so a variable without
its function fails at once, not in the middle of a sweep.
"""

from collections.abc import Callable, Iterable

import numpy as np

from rbstudy.archive.variables import DEPRECATED, VARIABLES
from rbstudy.numerics.state import RESULT_FIELDS
from rbstudy.pipeline import outputs, reference_outputs
from rbstudy.pipeline.batch_data import BatchData

__all__ = ["FORMULAS", "evaluate"]

_DRIVER_RESULTS = dict(RESULT_FIELDS)


def _formula(name: str) -> Callable[[BatchData], np.ndarray]:
    """The function ``(batch) -> values`` (case axis first) of output variable ``name``."""
    name = DEPRECATED.get(name, name)
    if name in _DRIVER_RESULTS:
        return outputs.driver_result(name)
    return getattr(reference_outputs, name, None) or getattr(outputs, name)


FORMULAS = {name: _formula(name) for name in VARIABLES}


def evaluate(names: Iterable[str], batch: BatchData) -> dict[str, np.ndarray]:
    """The values of the variables ``names`` for an `rbstudy.pipeline.batch_data.BatchData`."""
    return {name: FORMULAS[name](batch) for name in names}
