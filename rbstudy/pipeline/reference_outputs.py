"""The output variables of a batch's references, one function per variable as in
`rbstudy.pipeline.outputs` (`rbstudy.pipeline.formulas` binds both): which reference each
case has, its uncertainty where it is integrated, its float64 floor where it is a closed
form."""

import numpy as np

from rbstudy.physics import metrics
from rbstudy.pipeline.batch_data import BatchData

__all__: list[str] = []


def reference(batch: BatchData) -> np.ndarray:
    """The code of each case's reference in `rbstudy.physics.analytic.REFERENCE_KINDS`.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        int8
    """
    return batch.references.code.astype(np.int8)


def _uncertainty(batch: BatchData, measure: str) -> np.ndarray:
    """(B,) the reference's uncertainty in ``measure``: NaN where nothing checked it."""
    return batch.references.uncertainty[:, metrics.UNCERTAIN_MEASURES.index(measure)]


def reference_uncertainty(batch: BatchData) -> np.ndarray:
    """The reference's uncertainty in orientation.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        rad; NaN where nothing checked it.
    """
    return _uncertainty(batch, "orientation")


def float64_floor(batch: BatchData) -> np.ndarray:
    """The float64 floor of the reference's orientation at the last output time.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        rad; NaN where the reference is integrated.
    """
    return batch.references.floor


def reference_omega_uncertainty(batch: BatchData) -> np.ndarray:
    """The reference's relative uncertainty in body angular velocity.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        NaN where nothing checked it.
    """
    return _uncertainty(batch, "omega")


def reference_node_uncertainty(batch: BatchData) -> np.ndarray:
    """The reference's uncertainty in node positions.

    Parameters
    ----------
    batch : BatchData

    Returns
    -------
    ndarray, shape (B,)
        m; NaN where nothing checked it.
    """
    return _uncertainty(batch, "nodes")
