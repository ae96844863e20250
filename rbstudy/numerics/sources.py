"""A digest of the sources that compute results (numba-free).

It names numba's cache folder (`rbstudy.numerics.jit`) and enters every batch id
(`rbstudy.pipeline.batches`), so that neither a cached kernel nor a stored part of older code
is ever reused. What only presents stored numbers (the analysis layer, the command line) is
left out: editing it changes no result.
"""

import hashlib
import pathlib

__all__ = ["SOURCE_DIGEST"]

_PACKAGE = pathlib.Path(__file__).resolve().parents[1]
_PRESENTATION = ("analysis/", "cli.py", "__main__.py")


def _source_digest():
    digest = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*.py")):
        relative = path.relative_to(_PACKAGE).as_posix()
        if relative.startswith(_PRESENTATION):
            continue
        digest.update(relative.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


SOURCE_DIGEST = _source_digest()
