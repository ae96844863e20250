"""Study configs: YAML -> a validated, frozen `StudyConfig`, or a one-line `ConfigError`.

This first version reads a single-case study (name, title, scene, output, run); the sweep
block arrives with the sweep pipeline (issue 3). Every error names the file, the key path,
the value and the fix.
"""

import pathlib
from dataclasses import dataclass

import yaml

from rbstudy.errors import ConfigError, RbstudyError
from rbstudy.scenes import Scene, scene_from_mapping
from rbstudy.schemes import get_scheme
from rbstudy.simulate import steps_per

__all__ = ["StudyConfig", "load_study"]

_TOP_KEYS = ("name", "title", "scene", "output", "run")


@dataclass(frozen=True)
class StudyConfig:
    """A validated study: where it came from, its scene, output grid and run settings."""

    path: str
    text: str
    name: str
    title: str
    scene: Scene
    output_interval: float
    scheme: str
    options: dict
    dt: float


def _fail(path, key, message):
    raise ConfigError(f"{path}: {key}: {message}")


def _mapping(path, value, key, allowed):
    if not isinstance(value, dict):
        _fail(path, key, f"expected a mapping with keys {', '.join(allowed)}, got {value!r}")
    for name in value:
        if name not in allowed:
            _fail(path, f"{key}.{name}" if key else name,
                  f"unknown key; valid keys here: {', '.join(allowed)}")
    return value


def _positive(path, value, key):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        _fail(path, key, f"must be a number > 0, got {value!r}")
    return float(value)


def load_study(path):
    """Read and validate the study config at ``path``; nothing is run or written."""
    path = str(path)
    try:
        text = pathlib.Path(path).read_text()
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the config: {error.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        where = getattr(error, "problem_mark", None)
        line = f"line {where.line + 1}: " if where else ""
        raise ConfigError(f"{path}: {line}malformed YAML: {getattr(error, 'problem', error)}") \
            from None
    data = _mapping(path, data, "", _TOP_KEYS)
    for key in ("name", "scene", "run"):
        if key not in data:
            _fail(path, key, "missing")
    name = data["name"]
    if not isinstance(name, str) or not name.replace("_", "").replace("-", "").isalnum():
        _fail(path, "name", f"use letters, digits, '-' and '_' only (it names a folder), got {name!r}")
    try:
        scene = scene_from_mapping(data["scene"], source=path)
    except RbstudyError as error:
        raise ConfigError(str(error)) from None
    run = _mapping(path, data["run"], "run", ("scheme", "options", "dt"))
    if "scheme" not in run or "dt" not in run:
        _fail(path, "run", "needs scheme and dt")
    try:
        scheme = get_scheme(run["scheme"])
        options = dict(run.get("options") or {})
        scheme.option_row(options)
    except RbstudyError as error:
        raise ConfigError(f"{path}: run: {error}") from None
    dt = _positive(path, run["dt"], "run.dt")
    output = _mapping(path, data.get("output", {}), "output", ("interval",))
    interval = _positive(path, output.get("interval", dt), "output.interval")
    try:
        steps_per(interval, dt, "output interval")
    except RbstudyError as error:
        _fail(path, "run.dt", str(error))
    try:
        steps_per(scene.duration, interval, "duration")
    except RbstudyError as error:
        _fail(path, "output.interval", str(error).replace("dt =", "interval ="))
    return StudyConfig(path=path, text=text, name=name, title=str(data.get("title", name)),
                       scene=scene, output_interval=interval, scheme=scheme.name,
                       options=options, dt=dt)
