"""Reading swept columns: the shared steps of every reader of scene values held per scene.

A sweep's scene mapping holds columns (numpy arrays, one entry per scene) where it sweeps;
`rbstudy.inputs.reader.Reader` checks each value; these turn what it returns into arrays with
the scenes first, turn body vectors into the principal frame, and refuse a row by a condition,
naming the row (`rbstudy.inputs.scenes`, `rbstudy.inputs.assembly`, `rbstudy.inputs.loads`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from rbstudy.inputs.reader import Reader

__all__ = [
    "rows",
    "refuse",
    "symmetric_tensor",
    "in_principal",
    "one_row_if_alike",
    "read_files",
    "FilesRead",
    "file_bindings",
    "FileBinding",
]


def rows(vector: Iterable[Any], size: int) -> np.ndarray:
    """A vector as the reader returns it (floats and columns) -> (size, len) floats."""
    return np.stack([np.broadcast_to(np.asarray(v, dtype=float), (size,)) for v in vector], axis=-1)


def refuse(
    reader: Reader, bad: np.ndarray, key: str, message: Callable[[int], str], fix: str | None = None
) -> None:
    """Fail at the first row where ``bad`` (n,) holds; ``message(row)`` names its value."""
    if bad.any():
        row = int(np.argmax(bad))
        reader.fail(key, message(row), fix, row=row)


def symmetric_tensor(reader: Reader, value: Sequence[Any], key: str, size: int) -> np.ndarray:
    """A 3x3 tensor given as three rows of three numbers -> (size, 3, 3), refused unless
    symmetric (to 1e-12 relative)."""
    tensor = np.stack([rows(reader.vector(row, f"{key}[{i}]"), size) for i, row in enumerate(value)], axis=-2)
    refuse(
        reader,
        ~np.all(np.isclose(tensor, np.swapaxes(tensor, -1, -2), rtol=1e-12, atol=0.0), axis=(-2, -1)),
        key,
        lambda row: "the inertia tensor must be symmetric",
    )
    return tensor


def in_principal(axes: np.ndarray | None, vectors: np.ndarray) -> np.ndarray:
    """Input-frame vectors (n, ..., 3) in the principal frame (``axes`` (n, 3, 3) as columns,
    None for the identity); either may have one row for all n."""
    if axes is None:
        return vectors
    turn = axes.reshape(axes.shape[:1] + (1,) * (vectors.ndim - 2) + (3, 3))
    return (vectors[..., None, :] @ turn)[..., 0, :]


def one_row_if_alike(array: np.ndarray | None) -> np.ndarray | None:
    """``array`` (n, ...) as one row when every row equals the first (the scenes share it),
    else as it is (None too): what every scene shares is then computed once, not n times."""
    if array is None or len(array) <= 1 or not (array == array[:1]).all():
        return array
    return array[:1]


class FilesRead(NamedTuple):
    """What `read_files` read: each distinct file ``names`` once (an array of text), what was
    read of each (``contents``), and which one each scene takes (``chosen``, (n,))."""

    names: np.ndarray
    contents: list[Any]
    chosen: np.ndarray


def read_files(
    reader: Reader, files: Any, key: str, size: int, read: Callable[[Path], Any], what: str
) -> FilesRead:
    """Read the files named at ``key``, one name or a column of n (a sweep), each relative to
    the config: their `FilesRead`, the contents what ``read(path)`` returns for each. A name that is no text
    fails as not ``what`` ("a node table file"); an error inside a file keeps its place there
    and gains the first swept row that names the file."""
    fix = "give a file name, relative to the config's folder"
    if not isinstance(files, (str, np.ndarray)):  # one value, the same in every swept case
        reader.fail(key, f"expected {what}, got {files!r:.80}", fix)
    column = np.broadcast_to(np.asarray(files, dtype=object), (size,))
    refuse(
        reader,
        np.array([not isinstance(name, str) for name in column]),
        key,
        lambda row: f"expected {what}, got {column[row]!r:.80}",
        fix,
    )
    names, index = np.unique(column.astype(str), return_inverse=True)
    folder = Path(reader.source).parent
    contents = []
    for k, name in enumerate(names):
        try:
            contents.append(read(folder / name))
        except reader.kind as error:
            error.row = int(np.argmax(index == k)) if isinstance(files, np.ndarray) else None
            raise
    return FilesRead(names, contents, index)


class FileBinding(NamedTuple):
    """A table file a scene read: the config ``key`` that names it, its ``name`` and the
    sha256 ``digest`` of its content."""

    key: str
    name: str
    digest: str


def file_bindings(key: str, names: Iterable[Any], contents: Iterable[Any]) -> tuple[FileBinding, ...]:
    """The `FileBinding` of each file that `read_files` read at ``key``
    (``names`` and their ``contents``, each with a ``digest``): what a study's identity holds
    of its table files. Each name is bound to its own content: as a set of digests, two swept
    files whose contents were swapped looked unchanged, and their old results were reused."""
    return tuple(
        FileBinding(key, str(name), content.digest) for name, content in zip(names, contents, strict=True)
    )
