"""Reading a YAML file (a study config, a cluster file): UTF-8 text -> YAML -> plain Python
values, or a one-line `ConfigError`.

Beyond PyYAML's safe loader, it reads floats as YAML 1.2 does (``1e-3`` is a number, not a
string), keeps dates and other YAML 1.1 timestamps as text (a config has no dates),
refuses duplicate keys (the last one would silently win: an appended ``name: other``
renames the study), and refuses documents nested deeper than `MAX_DEPTH`, aliases that refer
to themselves, and aliases that expand to more than `MAX_VALUES` values (nine levels of nine
under one key are 490 million values: every later step that walks the config, from an error
message to a scene's identity, would exhaust the memory).
"""

import re

import yaml

from rbstudy.errors import ConfigError, InputError, one_line
from rbstudy.inputs.reader import read_input_file

__all__ = ["read_yaml_file", "parse_yaml", "MAX_DEPTH", "MAX_VALUES"]

# A study config is a few hundred values a few levels deep (scene.initial.angular_velocity
# .body is five): these bounds leave ample room.
MAX_DEPTH = 32
MAX_VALUES = 100_000


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2 floats, no timestamps and no duplicate keys."""

    def construct_mapping(self, node, deep=False):
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
    """(depth, number of values once every alias is expanded) of a composed YAML node.

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
    return measured[id(root)]


class _SelfReference(Exception):
    """An alias that contains itself (``&a [*a]``): legal YAML, endless data."""


def _check_extent(path, root):
    """Refuse what is nested too deeply, refers to itself or expands too far, naming the
    top-level key."""
    parts = root.value if isinstance(root, yaml.MappingNode) else [(None, root)]
    for key_node, value in parts:
        key = key_node.value if key_node is not None else None
        try:
            depth, size = _extent(value)
        except _SelfReference:
            raise ConfigError("an alias refers to itself", "write the values out", path, key) from None
        if depth > MAX_DEPTH:
            raise ConfigError(
                f"nested {depth} levels deep (at most {MAX_DEPTH})",
                "write it flat, as docs/config.md shows",
                path,
                key,
            )
        if size > MAX_VALUES:
            raise ConfigError(
                f"its aliases expand to {size:,} values (at most {MAX_VALUES:,})",
                "write the values out instead of nesting aliases",
                path,
                key,
            )


def read_yaml_file(path):
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


def parse_yaml(text, path):
    """The values of the YAML ``text`` (a file's, or a value given on the command line for
    the file at ``path``), read as `read_yaml_file` reads a file; a `ConfigError` at ``path``
    names what is wrong."""
    loader = _Loader(text)
    try:
        root = loader.get_single_node()  # composed once: measured, then built
        if root is None:
            return None
        _check_extent(path, root)
        return loader.construct_document(root)
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
    except yaml.YAMLError as error:
        where = getattr(error, "problem_mark", None)
        raise ConfigError(
            f"malformed YAML: {getattr(error, 'problem', error)}",
            source=path,
            key=f"line {where.line + 1}" if where else None,
        ) from None
    finally:
        loader.dispose()
