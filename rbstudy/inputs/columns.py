"""Reading swept columns: the shared steps of every reader of scene values held per scene.

A sweep's scene mapping holds columns (numpy arrays, one entry per scene) where it sweeps;
`rbstudy.inputs.reader.Reader` checks each value; these turn what it returns into arrays with
the scenes first, turn body vectors into the principal frame, and refuse a row by a condition,
naming the row (`rbstudy.inputs.scenes`, `rbstudy.inputs.assembly`, `rbstudy.inputs.loads`).
"""

from pathlib import Path

import numpy as np

__all__ = [
    "rows",
    "refuse",
    "symmetric_tensor",
    "in_principal",
    "one_row_if_alike",
    "read_files",
    "file_bindings",
]


def rows(vector, size):
    """A vector as the reader returns it (floats and columns) -> (size, len) floats."""
    return np.stack([np.broadcast_to(np.asarray(v, dtype=float), (size,)) for v in vector], axis=-1)


def refuse(reader, bad, key, message, fix=None):
    """Fail at the first row where ``bad`` (n,) holds; ``message(row)`` names its value."""
    if bad.any():
        row = int(np.argmax(bad))
        reader.fail(key, message(row), fix, row=row)


def symmetric_tensor(reader, value, key, size):
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


def in_principal(axes, vectors):
    """Input-frame vectors (n, ..., 3) in the principal frame (``axes`` (n, 3, 3) as columns,
    None for the identity); either may have one row for all n."""
    if axes is None:
        return vectors
    turn = axes.reshape(axes.shape[:1] + (1,) * (vectors.ndim - 2) + (3, 3))
    return (vectors[..., None, :] @ turn)[..., 0, :]


def one_row_if_alike(array):
    """``array`` (n, ...) as one row when every row equals the first (the scenes share it),
    else as it is (None too): what every scene shares is then computed once, not n times."""
    if array is None or len(array) <= 1 or not (array == array[:1]).all():
        return array
    return array[:1]


def read_files(reader, files, key, size, read, what):
    """Read the files named at ``key``, one name or a column of n (a sweep), each relative to
    the config: ``(names, contents, index)`` with each distinct name once, what ``read(path)``
    returns for it, and which one each of the n scenes takes (n,). A name that is no text
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
    return names, contents, index


def file_bindings(key, names, contents):
    """``(key, file name, sha256 digest)`` of each file that `read_files` read at ``key``
    (``names`` and their ``contents``, each with a ``digest``): what a study's identity holds
    of its table files. Each name is bound to its own content: as a set of digests, two swept
    files whose contents were swapped looked unchanged, and their old results were reused."""
    return tuple((key, str(name), content.digest) for name, content in zip(names, contents, strict=True))
