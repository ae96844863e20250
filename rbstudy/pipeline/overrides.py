"""Command-line overrides of a study config: ``--set KEY=VALUE`` -> the config's mapping with
the values written in, before it is validated (docs/config.md, "Overrides: --set").

KEY is a dotted path into the mapping (``sweep.dt.count``, ``run.options.alpha``; a list entry
by its index, ``scene.body.inertia.2``), VALUE is YAML, read as the file is read
(`rbstudy.inputs.yaml_file`), so ``3``, ``-0.1``, ``1e-3``, ``[1, 2]``, ``true`` and
``hht`` are what they would be in the file. A key the file does not give is created, with the
mappings above it: whether the study knows it is for validation to say, as it says of the
file's own keys (an unknown one with the key that was meant). A validation error in what an
override wrote names its key as ``--set <key>``; any other error of the study, which the
overrides may have caused, names the file "with" them.
"""

import copy
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, NoReturn

import yaml

from rbstudy.errors import ConfigError, InputError
from rbstudy.inputs.yaml_file import MAX_DEPTH, parse_yaml

__all__ = ["Override", "Overridden", "apply_overrides"]

# How a KEY=VALUE that is not one can be written.
_FORM = "write it as KEY=VALUE, for example --set sweep.dt.count=3"
# The first part of a sweep axis given by its dotted path (`rbstudy.pipeline.axes`): a new
# key with this head under `sweep` (or a zipped group) is that whole path, not nested mappings.
_AXIS_PATH_HEADS = ("scene", "run")


@dataclass(frozen=True)
class Override:
    """One ``--set``: ``assignment`` as given (``sweep.dt.count=3``), ``parts`` its key split
    at the dots, ``value`` its YAML value."""

    assignment: str
    parts: tuple[str, ...]
    value: object

    @property
    def key(self) -> str:
        return ".".join(self.parts)


@dataclass(frozen=True)
class Overridden:
    """A config's mapping with its overrides written in.

    source : the config file. data : the mapping to validate (the file's own is left as it
    was read). overrides : the `Override`s, in the order given (a later one wins). written :
    per override, the key path of what it wrote, in the reader's spelling
    (``scene.body.inertia[2]``), up to the first key the file did not have: an error at or
    below it is the override's.
    """

    source: str
    data: Any
    overrides: tuple[Override, ...]
    written: tuple[str, ...]

    @property
    def assignments(self) -> tuple[str, ...]:
        return tuple(override.assignment for override in self.overrides)

    def blame(self, error: InputError) -> InputError:
        """``error`` (an `InputError` from validating ``data``, a file's or study's) with its
        key's part that an override wrote named ``--set <key>``; with none, its source (when it
        is the config) named with the overrides, which may have made the mistake."""
        if not self.overrides:
            return error
        given = error.key.split(": ") if error.key else []  # `sweep (dt[1] = 0.003): run.dt`
        segments = [f"--set {segment}" if self._wrote(segment) else segment for segment in given]
        if segments != given:
            return type(error)(error.message, error.fix, error.source, ": ".join(segments), error.row)
        if error.source != self.source:  # a table file the config names: its own error
            return error
        with_ = " ".join(self._given())
        return type(error)(error.message, error.fix, f"{error.source} (with {with_})", error.key, error.row)

    def _wrote(self, key: str) -> bool:
        """Whether the key path ``key`` is at or below what an override wrote."""
        return any(key == path or key.startswith((f"{path}.", f"{path}[")) for path in self.written)

    def _given(self) -> list[str]:
        """``--set a=1`` per override, each on one line (a newline shown as ``\\n``)."""
        return [f"--set {text}".replace("\r", "\\r").replace("\n", "\\n") for text in self.assignments]

    def text(self, file_text: str) -> str:
        """The config text an archive stores: ``file_text`` itself without overrides, else the
        overridden mapping as YAML under a comment naming the overrides (the file's comments
        are not kept)."""
        if not self.overrides:
            return file_text
        header = [
            "# rbstudy: the config file's values with these applied (the file's comments are not kept):"
        ] + [f"#   {given}" for given in self._given()]
        return (
            "\n".join(header)
            + "\n"
            + yaml.safe_dump(self.data, sort_keys=False, default_flow_style=None, allow_unicode=True)
        )


def _parse(assignment: str, source: str) -> Override:
    """The `Override` of one ``KEY=VALUE``; a `ConfigError` at ``source`` says what is wrong."""
    key, equals, value = assignment.partition("=")
    key = key.strip()
    if not equals:
        raise ConfigError(f"no '=' in {assignment!r}", _FORM, source, f"--set {key}")
    parts = tuple(key.split("."))
    if len(parts) > MAX_DEPTH:  # no config nests so deep; finding the path would take minutes
        raise ConfigError(
            f"a key of {len(parts):,} dotted parts (a config nests at most {MAX_DEPTH} deep)",
            _FORM,
            source,
            f"--set {key[:40]}..." if len(key) > 40 else f"--set {key}",
        )
    if not all(part.strip() for part in parts):
        raise ConfigError(
            f"{key!r} is no dotted path of keys", _FORM, source, f"--set {key}" if key else "--set"
        )
    try:
        parsed = parse_yaml(value, source)
    except ConfigError as error:
        raise error.located(key=f"--set {key}") from None
    return Override(assignment, parts, parsed)


def _child_key(node: dict[Any, Any], rest: list[str], above: list[str]) -> tuple[Any, int]:
    """(key, how many parts of ``rest`` it takes) in the mapping ``node`` at the key path
    ``above`` (a list of keys): the longest dotted key ``node`` holds that ``rest`` spells (the
    sweep's ``run.options.alpha``), else the first part; a new sweep axis given by its path is
    that whole path."""
    held = {str(key): key for key in node}  # `nodes: {2: ...}`: YAML made the name a number
    for taken in range(len(rest), 0, -1):
        joined = ".".join(rest[:taken])
        if joined in held:
            return held[joined], taken
    in_sweep = above == ["sweep"] or (len(above) == 3 and above[:2] == ["sweep", "zip"])
    if in_sweep and rest[0] in _AXIS_PATH_HEADS and len(rest) > 1:
        return ".".join(rest), len(rest)
    return rest[0], 1


def _write(root: dict[Any, Any], override: Override, source: str) -> str:
    """Write ``override`` into the mapping ``root`` in place, each mapping and list on its path
    copied first (an alias of the file shares them with another key, which must keep its
    value); returns the path it wrote in the reader's spelling, up to the first new key."""

    def fail(message: str, fix: str) -> NoReturn:
        raise ConfigError(message, fix, source, f"--set {override.key}")

    node: Any = root  # a mapping or list of the YAML read, then one of its values
    rest = list(override.parts)
    above: list[str] = []  # the keys of the path so far
    spelled = ""
    written: str | None = None
    while rest:
        if isinstance(node, list):
            part = rest[0]
            if not part.isdigit() or int(part) >= len(node):
                fail(
                    f"{part!r} is not an entry of the list of {len(node)} at {spelled}",
                    f"use an index 0..{len(node) - 1}",
                )
            key, taken, spelled = int(part), 1, f"{spelled}[{part}]"
        elif isinstance(node, dict):
            key, taken = _child_key(node, rest, above)
            spelled = f"{spelled}.{key}" if spelled else str(key)
            if node.get(key) is None:  # absent, or empty (`output:` reads as None)
                written = written or spelled
        else:
            fail(
                f"{spelled} holds {node!r:.60}, not a mapping or list",
                f"set {spelled} itself, or a key under a mapping",
            )
        above.append(str(key))
        rest = rest[taken:]
        if not rest:
            node[key] = override.value
            break
        child = node[key] if isinstance(node, list) else node.get(key)
        if child is None:
            child = node[key] = {}
        elif isinstance(child, (dict, list)):
            child = node[key] = copy.copy(child)
        node = child
    return written or spelled


def apply_overrides(data: Any, assignments: Iterable[str], source: str) -> Overridden:
    """The `Overridden` config of the mapping ``data`` read from ``source`` and the
    ``--set`` texts ``assignments`` (``KEY=VALUE``), applied in order; a `ConfigError` for a
    malformed one, a value YAML cannot read, or a path through a value that is no mapping.
    A file that is no mapping is left to validation to refuse."""
    overrides = tuple(_parse(text, source) for text in assignments)
    if not overrides or not isinstance(data, (dict, type(None))):
        return Overridden(source, data, overrides, ())
    root = dict(data or {})
    written = tuple(_write(root, override, source) for override in overrides)
    return Overridden(source, root, overrides, written)
