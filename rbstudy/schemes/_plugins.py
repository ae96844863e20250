"""Schemes from other packages: the entry points of the group ``rbstudy.schemes``.

A package registers a scheme by naming a `Scheme` object under the scheme's name in its
metadata (docs/extending.md):

    [project.entry-points."rbstudy.schemes"]
    semi_implicit = "rbstudy_semi_implicit.compiled:SCHEME"

`load_plugins` loads each one, after rbstudy's own adapters of other engines (`ENGINES`,
`rbstudy.engines`), which are loaded the same way. A plug-in that cannot be loaded here
never stops rbstudy: it is listed as unavailable, with why and what to do (`Unavailable`).
A package whose scheme needs something absent (an engine's Python bindings) says so by
raising `SchemeUnavailable` when its module is imported, with the install command as the fix.

Each plug-in scheme carries a digest of its package's sources (`Scheme.code_digest`,
`rbstudy.numerics.sources.package_digest`), which enters the ids of its batches: parts
computed by older code of the plug-in are never reused, as rbstudy's own source digest
ensures for the built-in schemes. A plug-in's module must not read the registry when it is
imported (`BUILTIN` is there for that): imported first by a user, it would find itself
half-initialised and be listed unavailable.
"""

import importlib.metadata
from dataclasses import dataclass, replace

from rbstudy.errors import first_line
from rbstudy.numerics.sources import package_digest
from rbstudy.schemes._registry import Scheme

__all__ = ["GROUP", "ENGINES", "SchemeUnavailable", "Unavailable", "load_plugins"]

GROUP = "rbstudy.schemes"
# rbstudy's own adapters of other engines (`rbstudy.engines`), loaded as plug-ins are:
# name -> "module:attribute". Each names its engine and version in its `origin` and
# `code_digest`, so that another version of the engine never reuses a part.
ENGINES = {
    "mujoco_euler": "rbstudy.engines.mujoco:EULER",
    "mujoco_implicitfast": "rbstudy.engines.mujoco:IMPLICITFAST",
    "mujoco_implicit": "rbstudy.engines.mujoco:IMPLICIT",
    "mujoco_rk4": "rbstudy.engines.mujoco:RK4",
}


class SchemeUnavailable(ImportError):  # noqa: N818 (read as "raise SchemeUnavailable(...)")
    """Raised by a plug-in's module when its scheme cannot run here: ``reason`` says why,
    ``fix`` what to run (``pip install "mujoco>=4.0"``)."""

    def __init__(self, reason, fix):
        super().__init__(reason)
        self.reason, self.fix = reason, fix


@dataclass(frozen=True)
class Unavailable:
    """A registered scheme that cannot run here: ``reason``, ``fix`` and ``origin`` (the
    package that registered it)."""

    name: str
    reason: str
    fix: str
    origin: str


def _own(entry_point):
    """An engine adapter of rbstudy's own (`ENGINES`)."""
    return entry_point.module.startswith("rbstudy.")


def _origin(entry_point):
    if _own(entry_point):
        return "rbstudy"
    dist = getattr(entry_point, "dist", None)
    return f"{dist.name} {dist.version}" if dist is not None else entry_point.value


def _load(entry_point, taken):
    """The `Scheme` of one entry point (with its code digest and origin), or why not."""
    origin = _origin(entry_point)
    package = origin.split()[0]
    try:
        scheme = entry_point.load()
        digest = None if _own(entry_point) else package_digest(entry_point.module)
    except SchemeUnavailable as error:
        return Unavailable(entry_point.name, error.reason, error.fix, origin)
    except Exception as error:  # a plug-in's bug must not stop the other schemes
        return Unavailable(entry_point.name, f"cannot be loaded ({first_line(error)})",
                           f"reinstall or fix {package}", origin)
    if not isinstance(scheme, Scheme):
        return Unavailable(entry_point.name,
                           f"{entry_point.value} is a {type(scheme).__name__}, not a Scheme",
                           f"point the entry point at a rbstudy.schemes.Scheme in {package}",
                           origin)
    if scheme.name != entry_point.name:
        return Unavailable(entry_point.name,
                           f"{entry_point.value} is the scheme {scheme.name!r}",
                           "name the entry point as its scheme", origin)
    if entry_point.name in taken:
        return Unavailable(entry_point.name, f"the name is taken by {taken[entry_point.name]}",
                           f"rename the scheme in {package}", origin)
    if _own(entry_point):  # rbstudy's source digest covers the adapter; it names the engine
        return scheme
    return replace(scheme, origin=origin, code_digest=digest)


def load_plugins(builtin):
    """The engine adapters' and plug-ins' schemes of this environment: (name -> `Scheme`,
    name -> `Unavailable`). ``builtin`` are rbstudy's own schemes, whose names a plug-in may
    not take."""
    taken = {name: "rbstudy's own scheme" for name in builtin}
    found, unavailable = {}, {}
    engines = [importlib.metadata.EntryPoint(name, value, GROUP)
               for name, value in ENGINES.items()]
    for entry_point in [*engines, *sorted(importlib.metadata.entry_points(group=GROUP),
                                          key=lambda point: point.name)]:
        loaded = _load(entry_point, taken)
        if isinstance(loaded, Unavailable):
            unavailable[loaded.name] = loaded
        else:
            found[loaded.name] = loaded
            taken[loaded.name] = loaded.origin
    return found, unavailable
