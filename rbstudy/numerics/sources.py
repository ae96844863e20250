"""A digest of the sources that compute results (numba-free).

It names numba's cache folder (`rbstudy.numerics.jit`) and enters every batch id
(`rbstudy.pipeline.batches`), so that neither a cached kernel nor a stored part of older code
is ever reused. What only presents stored numbers (the analysis layer, the command line) is
left out: editing it changes no result.
"""

import hashlib
import importlib.util
import pathlib

__all__ = ["SOURCE_DIGEST", "package_digest"]

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


def package_digest(module_name: str) -> str:
    """A digest of the Python sources of the top-level package of ``module_name`` (every module
    of it, helpers included; each folder of a namespace package), or of the module alone when it
    is in no package: what names a plug-in's code in its batch ids, its generated entry modules
    and its kernels' cache (`rbstudy.numerics.jit`).

    Parameters
    ----------
    module_name : str
        A dotted module name.

    Returns
    -------
    str
        16 hexadecimal digits.

    Raises
    ------
    ValueError
        Where the sources cannot be read (a zipped install).
    """
    spec = importlib.util.find_spec(module_name.split(".")[0])
    if spec is None:
        raise ValueError(f"no module {module_name!r} to read")
    if spec.submodule_search_locations:
        roots = [pathlib.Path(folder) for folder in spec.submodule_search_locations]
        files = [(root, path) for root in roots for path in sorted(root.rglob("*.py"))]
    elif spec.origin and spec.has_location:
        origin = pathlib.Path(spec.origin)
        files = [(origin.parent, origin)]
    else:
        raise ValueError(f"the sources of {module_name!r} are not files")
    digest = hashlib.sha256()
    try:
        for root, path in files:
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
    except OSError as error:
        raise ValueError(f"cannot read the sources of {module_name!r}: {error}") from None
    return digest.hexdigest()[:16]
