"""What this machine lets the process use, without loading numba: the command line asks it
for drawing figures, the driver for its threads."""

import os

__all__ = ["default_threads"]


def default_threads():
    """Cores this process may use (a SLURM share, a container's limit).

    Returns
    -------
    int
    """
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
