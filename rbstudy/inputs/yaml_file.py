"""Reading a YAML file (a study config, a cluster file): UTF-8 text -> YAML -> plain Python
values, or a one-line `ConfigError`.

Beyond PyYAML's safe loader, it reads floats as YAML 1.2 does (``1e-3`` is a number, not a
string), keeps dates and other YAML 1.1 timestamps as text (a config has no dates),
refuses duplicate keys (the last one would silently win: an appended ``name: other``
renames the study), and refuses non-printable characters, documents nested deeper than
`MAX_DEPTH`, aliases that refer to themselves, and aliases that add more than `MAX_VALUES`
values to what is written (nine levels of nine under one key are 490 million values: every
later step that walks the config, from an error message to a scene's identity, would exhaust
the memory). What is written is bounded too, before it is composed (PyYAML composes about
20,000 values a second): a list or mapping of at most `MAX_ENTRIES` entries, a document of
at most `MAX_WRITTEN` values.
"""

import os
import re
from typing import Any

import yaml

from rbstudy.errors import ConfigError, InputError, one_line
from rbstudy.inputs.reader import read_input_file

__all__ = ["read_yaml_file", "parse_yaml", "MAX_DEPTH", "MAX_VALUES", "MAX_ENTRIES", "MAX_WRITTEN"]

# A study config is a few hundred values a few levels deep (scene.initial.angular_velocity
# .body is five): these bounds leave ample room.
MAX_DEPTH = 32
MAX_VALUES = 100_000
# A swept axis has at most a million values (`rbstudy.pipeline.axes.MAX_CASES`), and a zip
# of a few such axes a few million: what may be written, beyond which composing the text
# would take minutes and gigabytes (PyYAML's nodes, ~500 bytes a value).
MAX_ENTRIES = 1_000_000
MAX_WRITTEN = 4_000_000
# The libyaml event parser, when PyYAML has it: counting what is written is many times faster
# with it than with PyYAML's own.
_EventParser = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2 floats, no timestamps and no duplicate keys."""

    def construct_mapping(self, node, deep=False):
        if not isinstance(node, yaml.MappingNode):  # `!!map [1]`: PyYAML's own error says so
            return super().construct_mapping(node, deep)
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue  # `<<: *base` merges another mapping in: not a key of its own
            key = self.construct_object(key_node, deep=True)
            if not isinstance(key, (str, int, float, bool)):
                continue  # an unhashable key fails in PyYAML's own construction
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"duplicate key {key!r}: give each key once (the later one would silently win)",
                    key_node.start_mark,
                )
            seen.add(key)
        return super().construct_mapping(node, deep)


# YAML 1.1 (PyYAML) takes ``1e-3`` and ``1.0e4`` for strings: exponents without a sign or
# without a dot. Study configs are full of such numbers; read them as floats.
_Loader.yaml_implicit_resolvers = {
    first: [(tag, pattern) for tag, pattern in resolvers if tag != "tag:yaml.org,2002:timestamp"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)$"),
    list("-+0123456789"),
)


def _extent(root):
    """(depth, number of values once every alias is expanded, number of values written) of
    a composed YAML node.

    Iterative and memoised by node: an alias is the same node object, so a document of
    nested aliases is measured in time proportional to its text, not to its expansion.
    """
    measured, open_ = {}, set()  # finished nodes; nodes whose children are being measured
    stack = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if id(node) in measured:
            continue
        children = (
            [item for pair in node.value for item in pair]
            if isinstance(node, yaml.MappingNode)
            else node.value
            if isinstance(node, yaml.SequenceNode)
            else []
        )
        if not children_done:
            if id(node) in open_:
                raise _SelfReference()
            open_.add(id(node))
            stack.append((node, True))
            stack.extend((child, False) for child in children if id(child) not in measured)
            continue
        open_.discard(id(node))
        depth = 1 + max((measured[id(c)][0] for c in children), default=0)
        size = 1 + sum(measured[id(c)][1] for c in children)
        measured[id(node)] = (depth, size)
    return (*measured[id(root)], len(measured))


class _SelfReference(Exception):
    """An alias that contains itself (``&a [*a]``): legal YAML, endless data."""


def _check_extent(path, root):
    """Refuse what is nested too deeply, refers to itself or expands too far, naming the
    top-level key."""
    parts = root.value if isinstance(root, yaml.MappingNode) else [(None, root)]
    for key_node, value in parts:
        key = key_node.value if key_node is not None else None
        try:
            depth, size, written = _extent(value)
        except _SelfReference:
            raise ConfigError("an alias refers to itself", "write the values out", path, key) from None
        if depth > MAX_DEPTH:
            raise ConfigError(
                f"nested {depth} levels deep (at most {MAX_DEPTH})",
                "write it flat, as docs/config.md shows",
                path,
                key,
            )
        if size - written > MAX_VALUES:
            raise ConfigError(
                f"its aliases expand to {size:,} values (at most {MAX_VALUES:,} more than the "
                f"{written:,} written)",
                "write the values out instead of nesting aliases",
                path,
                key,
            )


class _Collection:
    """A list or mapping being counted by `_check_written`: where it is, and its entries."""

    __slots__ = ("where", "mapping", "count", "key")

    def __init__(self, where, mapping):
        self.where, self.mapping, self.count, self.key = where, mapping, 0, "?"

    @property
    def entries(self):
        return self.count // 2 if self.mapping else self.count

    def child(self, event):
        """Count the node ``event`` in; the key path of what it starts."""
        self.count += 1
        if self.mapping and self.count % 2:  # a key: its value is the next node
            self.key = event.value if isinstance(event, yaml.ScalarEvent) else "?"
            return None
        return f"{self.where}.{self.key}".lstrip(".") if self.mapping else f"{self.where}[{self.count - 1}]"

    def too_long(self, path, more=""):
        kind = "mapping" if self.mapping else "list"
        return ConfigError(
            f"a {kind} of {more}{self.entries:,} entries (at most {MAX_ENTRIES:,}, an axis's most values)",
            "split the study into several",
            path,
            self.where or None,
        )


_STARTS = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
_ENDS = (yaml.SequenceEndEvent, yaml.MappingEndEvent)


def _check_written(text, path):
    """Refuse a list or mapping of more than `MAX_ENTRIES` entries, or a document of more than
    `MAX_WRITTEN` values, counted on the parser's events before anything is composed (the
    slow step). What the parser cannot read is left to the composer, which says it in its
    own words."""
    parser, open_, total = _EventParser(text), [], 0
    try:
        while parser.check_event():
            event = parser.get_event()
            if isinstance(event, _ENDS):
                closed = open_.pop()
                if closed.entries > MAX_ENTRIES:
                    raise closed.too_long(path)
                continue
            if not isinstance(event, yaml.NodeEvent):  # the stream's and documents' bounds
                continue
            total += 1
            where = open_[-1].child(event) if open_ else ""
            if isinstance(event, _STARTS):
                open_.append(_Collection(where, isinstance(event, yaml.MappingStartEvent)))
            if total > MAX_WRITTEN:
                longest = max(open_, key=lambda collection: collection.entries, default=None)
                if longest is not None and longest.entries > MAX_ENTRIES:
                    raise longest.too_long(path, more="more than ")
                raise ConfigError(
                    f"holds more than {MAX_WRITTEN:,} values", "split the study into several", path
                )
    except yaml.YAMLError:
        return
    finally:
        parser.dispose()


def read_yaml_file(path: str | os.PathLike[str]) -> tuple[str, Any]:
    """The text of the YAML file at ``path`` and its values; a `ConfigError` names what is
    wrong with the file (unreadable, no regular file, larger than
    `rbstudy.inputs.reader.MAX_INPUT_BYTES`, not UTF-8, malformed YAML, too deep or too large)."""
    try:
        text = read_input_file(path, "the file", "give the path of a YAML file").decode("utf-8")
    except InputError as error:
        raise error.located(kind=ConfigError) from None
    except UnicodeDecodeError as error:
        raise ConfigError(
            f"is not UTF-8 text (byte {error.object[error.start]:#04x} at offset {error.start})",
            "save the file as UTF-8",
            path,
        ) from None
    return text, parse_yaml(text, path)


def parse_yaml(text: str, path: str | os.PathLike[str]) -> Any:
    """The values of the YAML ``text`` (a file's, or a value given on the command line for
    the file at ``path``), read as `read_yaml_file` reads a file; a `ConfigError` at ``path``
    names what is wrong."""
    loader = None
    try:
        loader = _Loader(text)  # refuses a non-printable character at once
        _check_written(text, path)
        root = loader.get_single_node()  # composed once: measured, then built
        if root is None:
            return None
        _check_extent(path, root)
        return _constructed(loader, root, path)
    except RecursionError:
        raise ConfigError(
            "nested too deeply to read", "write it flat, as docs/config.md shows", path
        ) from None
    except (ValueError, OverflowError) as error:  # a number too long for Python to convert
        raise ConfigError(
            f"holds a value that cannot be read ({one_line(error)})",
            "write numbers with at most 17 significant digits",
            path,
        ) from None
    except yaml.reader.ReaderError as error:
        raise _unprintable(text, error.position, path) from None
    except yaml.YAMLError as error:
        where = getattr(error, "problem_mark", None)
        raise ConfigError(
            f"malformed YAML: {getattr(error, 'problem', error)}",
            source=path,
            key=f"line {where.line + 1}" if where else None,
        ) from None
    finally:
        if loader is not None:
            loader.dispose()


def _constructed(loader, root, path):
    """The values of the composed document ``root``. PyYAML's constructors of explicit tags
    fail on values they were not written for (``!!float ""``, ``!!bool x``, ``!!timestamp
    x``) with Python's own errors: said here in one line."""
    try:
        return loader.construct_document(root)
    except (IndexError, KeyError, AttributeError) as error:
        raise ConfigError(
            f"holds a value its tag cannot make ({type(error).__name__}: {one_line(error)})",
            "write the value without a !!tag",
            path,
        ) from None


def _unprintable(text, position, path):
    """The `ConfigError` of the character YAML refuses at ``position`` of ``text`` (a control
    character such as a form feed, even in a comment)."""
    line = text.count("\n", 0, position) + 1
    column = position - (text.rfind("\n", 0, position) + 1) + 1
    code = ord(text[position])
    escape = f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"
    return ConfigError(
        f"holds the non-printable character U+{code:04X}, which YAML does not allow anywhere, "
        "even in a comment",
        f"delete it (in a double-quoted string, write it as {escape})",
        path,
        f"line {line}, column {column}",
    )
