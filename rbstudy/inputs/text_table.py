"""Text tables: the lines of a node table or a load table file, split into fields.

Both tables are written by hand or exported from a spreadsheet (docs/config.md): one record
per line, fields separated by commas (CSV) or by white space, split by the standard `csv`
module. Lines starting with ``#`` and blank lines are skipped, a field may be quoted with
double quotes (``"node 7, left"``: its comma or space is part of it), a CSV line may end with
a comma, and a UTF-8 byte-order mark is skipped. What the fields mean is the reader's of each
table (`rbstudy.inputs.node_table`, `rbstudy.inputs.load_table`).
"""

import csv
import hashlib
import math
import os
from collections.abc import Iterator

from rbstudy.errors import InputError
from rbstudy.inputs.reader import Reader, read_input_file

__all__ = ["fields", "table_lines", "finite"]


def fields(line: str) -> list[str]:
    """The fields of a line, split by `csv`: by commas (one trailing comma allowed), or by
    white space where no comma outside quotes separates any; each without its quotes and
    surrounding spaces. A line `csv` cannot split raises `csv.Error`."""
    if "," in line:
        parts = next(csv.reader([line], skipinitialspace=True))
        if len(parts) > 1:
            return [part.strip() for part in (parts[:-1] if not parts[-1].strip() else parts)]
    # csv takes one delimiter: tabs become spaces, runs of spaces one (skipinitialspace)
    parts = next(csv.reader([line.replace("\t", " ").strip()], delimiter=" ", skipinitialspace=True))
    return [part.strip() for part in parts]


def table_lines(
    path: str | os.PathLike[str], reader: Reader, what: str, fix: str
) -> tuple[str, Iterator[tuple[int, list[str]]]]:
    """The sha256 digest of the file ``path`` (batch ids change when a table does) and its
    records, ``(line number, fields)``, one at a time; a file that cannot be read fails through ``reader``
    at the key "table", as ``what`` ("the node table"), with ``fix`` (a FIFO, a device or a
    file past `rbstudy.inputs.reader.MAX_INPUT_BYTES` too), and a line that cannot be split at its
    line."""
    try:
        data = read_input_file(path, what, fix)
    except InputError as error:
        raise reader.locate(error, "table") from None
    try:
        text = data.decode("utf-8-sig")  # a spreadsheet's export may start with a BOM
    except UnicodeDecodeError as error:
        reader.fail("table", f"cannot read {what}: {error}", fix)
    return hashlib.sha256(data).hexdigest(), _records(text, reader, fix)


def _records(text, reader, fix):
    """``(line number, fields)`` of each record of ``text``, split as they are read: a
    million lines held split at once took ~300 MiB."""
    for number, line in enumerate(_lines(text), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            try:
                split = fields(line)
            except csv.Error as error:  # a lone carriage return, a field past csv's limit
                reader.fail(f"line {number}", f"cannot split the line into fields ({error})", fix)
            yield number, split


def _lines(text):
    """The lines of ``text`` one at a time (``\n`` or ``\r\n`` ends one), without the list of
    them all that ``str.splitlines`` builds: ~90 MiB for a table of a million rows."""
    start = 0
    while start < len(text):
        end = text.find("\n", start)
        end = len(text) if end < 0 else end
        yield text[start:end].removesuffix("\r")
        start = end + 1


def finite(field: str) -> float | None:
    """The field as a finite float, or None (text, NaN or infinity)."""
    try:
        value = float(field)
    except ValueError:
        return None
    return value if math.isfinite(value) else None
