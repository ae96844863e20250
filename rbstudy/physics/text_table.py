"""Text tables: the lines of a node table or a load table file, split into fields.

Both tables are written by hand or exported from a spreadsheet (docs/config.md): one record
per line, fields separated by commas (CSV) or by white space. Lines starting with ``#`` and
blank lines are skipped, fields may be quoted, a CSV line may end with a comma, and a UTF-8
byte-order mark is skipped. What the fields mean is the reader's of each table
(`rbstudy.physics.node_table`, `rbstudy.physics.load_table`).
"""

import hashlib
import math

from rbstudy.errors import InputError
from rbstudy.reader import read_input_file

__all__ = ["fields", "table_lines", "finite"]


def fields(line):
    """The fields of a line: by commas (one trailing comma allowed) or by white space, each
    without surrounding quotes (a spreadsheet's export quotes text)."""
    if "," in line:
        parts = [part.strip() for part in line.split(",")]
        if len(parts) > 1 and not parts[-1]:
            parts.pop()
    else:
        parts = line.split()
    return [part.strip('"').strip("'") for part in parts]


def table_lines(path, reader, what, fix):
    """The sha256 digest of the file ``path`` (batch ids change when a table does) and its
    records, ``(line number, fields)``, one at a time; a file that cannot be read fails through ``reader``
    at the key "table", as ``what`` ("the node table"), with ``fix`` (a FIFO, a device or a
    file past `rbstudy.reader.MAX_INPUT_BYTES` too)."""
    try:
        data = read_input_file(path, what, fix)
    except InputError as error:
        raise reader.locate(error, "table") from None
    try:
        text = data.decode("utf-8-sig")  # a spreadsheet's export may start with a BOM
    except UnicodeDecodeError as error:
        reader.fail("table", f"cannot read {what}: {error}", fix)
    # split as they are read: a million lines held split at once took ~300 MiB
    records = ((number, fields(line)) for number, line in enumerate(_lines(text), start=1)
               if line.strip() and not line.lstrip().startswith("#"))
    return hashlib.sha256(data).hexdigest(), records


def _lines(text):
    """The lines of ``text`` one at a time (``\n`` or ``\r\n`` ends one), without the list of
    them all that ``str.splitlines`` builds: ~90 MiB for a table of a million rows."""
    start = 0
    while start < len(text):
        end = text.find("\n", start)
        end = len(text) if end < 0 else end
        yield text[start:end].removesuffix("\r")
        start = end + 1


def finite(field):
    """The field as a finite float, or None (text, NaN or infinity)."""
    try:
        value = float(field)
    except ValueError:
        return None
    return value if math.isfinite(value) else None
