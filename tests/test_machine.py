"""What the process asks of the machine: memory given back after a large transient."""

import os
import platform
import subprocess
import sys

import pytest

# A child that frees 300 MiB of blocks glibc keeps in its heap, then prints its resident MiB
# before and after return_free_memory.
_CHILD = """
import numpy as np
from rbstudy.numerics.machine import return_free_memory

def resident():
    return int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20

large = np.ones(2**21)  # 16 MiB: its free raises glibc's mmap threshold, so that smaller
del large  # blocks come from the heap
blocks = [np.ones(2**17) for _ in range(300)]  # 300 MiB of 1 MiB blocks
pinned = np.ones(2**17)  # above them: the heap's top cannot shrink past it
del blocks
before = resident()
return_free_memory()
print(before, resident())
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc_trim is glibc's")
def test_freed_memory_goes_back_to_the_system():
    # without glibc's tunables: distributed's nanny sets MALLOC_TRIM_THRESHOLD_ in the
    # environment of the process that starts a cluster (tests/test_cluster.py), and with it
    # glibc gives the blocks back itself
    plain = {name: value for name, value in os.environ.items() if not name.startswith("MALLOC_")}
    done = subprocess.run(
        [sys.executable, "-c", _CHILD], capture_output=True, text=True, check=True, env=plain
    )
    before, after = map(float, done.stdout.split())
    assert before - after > 200, (before, after)
