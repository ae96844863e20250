"""Print the throughput figures of docs/performance.md (same as `rbstudy bench`).

Usage: python pipelines/bench.py [SCHEME ...]
"""

import sys

from rbstudy.bench import run_bench

if __name__ == "__main__":
    run_bench(schemes=sys.argv[1:] or None)
