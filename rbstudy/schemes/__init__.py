"""The scheme registry: rbstudy's own schemes and those other packages register.

Every module of this package that defines ``SCHEME`` is one of rbstudy's schemes: adding a
scheme means adding one file here; config validation, `rbstudy schemes`, the docs table and
the tests all read `SCHEMES`. Other packages add theirs through the entry-point group
``rbstudy.schemes`` (`rbstudy.schemes._plugins`, docs/extending.md); those that cannot run
here are listed by `unavailable_schemes`, with why and the fix.

The engine adapters and the plug-ins are loaded when a name asks for them (`_Registry`), not
when this package is imported: a plug-in's module imports this package for `Scheme`, and
must find it complete; and a study of rbstudy's own schemes must not wait for, nor be
stopped by, another package's code.
"""

import importlib
import pkgutil
import threading
from collections.abc import Iterable, Mapping

from rbstudy.errors import SchemeError, did_you_mean
from rbstudy.schemes._composition import ORDERS as COMPOSITION_ORDERS
from rbstudy.schemes._composition import stage_reach as composition_reach
from rbstudy.schemes._plugins import (
    ENGINES,
    SchemeUnavailable,
    Unavailable,
    load_engines,
    load_plugins,
)
from rbstudy.schemes._ready import get_ready
from rbstudy.schemes._registry import GROUPS, INVARIANTS, KINDS, Option, Scheme, Style, option_slots

__all__ = [
    "SCHEMES",
    "BUILTIN",
    "GROUPS",
    "INVARIANTS",
    "KINDS",
    "COMPOSITION_ORDERS",
    "Option",
    "Scheme",
    "SchemeUnavailable",
    "Unavailable",
    "composition_reach",
    "get_scheme",
    "get_ready",
    "unavailable_schemes",
    "scheme_groups",
    "expand_groups",
    "scheme_styles",
    "Style",
    "option_slots",
]


def _discover():
    found = {}
    for module_info in pkgutil.iter_modules(__path__):
        if module_info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{module_info.name}")
        scheme = module.SCHEME
        found[scheme.name] = scheme
    return dict(sorted(found.items()))


class _Registry(Mapping):
    """name -> `Scheme`: rbstudy's own, then the engine adapters' and the plug-ins', each
    group loaded the first time a name is looked up that only it may hold, or the whole
    registry is read (listed, iterated). So a study of rbstudy's own schemes never imports
    another package's code, and one of MuJoCo's imports MuJoCo and no plug-in.

    Other threads wait for a group's loading; a plug-in that reads the registry while it is
    loaded (the same thread) sees rbstudy's own schemes and what is loaded already."""

    def __init__(self, builtin):
        self._builtin = builtin
        self._groups = {}  # loader -> (name -> Scheme, name -> Unavailable), once loaded
        self._lock = threading.RLock()
        self._loading = set()

    def _group(self, load):
        """The schemes of ``load`` (`load_engines` or `load_plugins`): (found, unavailable)."""
        if load in self._groups:
            return self._groups[load]
        with self._lock:
            if load not in self._groups:
                if load in self._loading:
                    return {}, {}
                self._loading.add(load)
                try:
                    self._groups[load] = load(self._builtin)
                finally:
                    self._loading.discard(load)
        return self._groups[load]

    def _loader(self, name):
        return load_engines if name in ENGINES else load_plugins

    def find(self, name):
        """The `Scheme` or the `Unavailable` registered as ``name`` (None: neither), loading
        only the group that may hold it."""
        if name in self._builtin:
            return self._builtin[name]
        found, unavailable = self._group(self._loader(name))
        return found.get(name) or unavailable.get(name)

    def unavailable(self):
        return {
            name: why for load in (load_engines, load_plugins) for name, why in self._group(load)[1].items()
        }

    def __getitem__(self, name):
        scheme = self.find(name) if isinstance(name, str) else None
        if not isinstance(scheme, Scheme):
            raise KeyError(name)
        return scheme

    def __iter__(self):
        return iter({**self._builtin, **self._group(load_engines)[0], **self._group(load_plugins)[0]})

    def __len__(self):
        return sum(1 for _ in self)


BUILTIN = _discover()
SCHEMES = _Registry(BUILTIN)


def unavailable_schemes() -> dict[str, Unavailable]:
    """name -> `Unavailable`: the registered schemes that cannot run here."""
    return SCHEMES.unavailable()


def get_scheme(name: str) -> Scheme:
    """The registered scheme ``name``; an unknown name raises `SchemeError` listing the valid
    ones, an unavailable one says why and how to make it available."""
    found = SCHEMES.find(name) if isinstance(name, str) else None
    if isinstance(found, Scheme):
        return found
    if isinstance(found, Unavailable):
        raise SchemeError(
            f"scheme {name!r} ({found.origin}) is not available here: {found.reason}", found.fix
        )
    valid = ", ".join(SCHEMES)  # every group loaded: the list is whole
    raise SchemeError(f"unknown scheme {name!r}{did_you_mean(name, SCHEMES)}", f"valid schemes: {valid}")


def scheme_styles(names: Iterable[str]) -> dict[str, Style]:
    """name -> `Style` of each of the schemes ``names`` that is registered here with a style
    (the figures give the others, and the schemes not installed here, one of their own)."""
    found = {name: SCHEMES.find(name) for name in names}
    return {
        name: scheme.style
        for name, scheme in found.items()
        if isinstance(scheme, Scheme) and scheme.style is not None
    }


# The groups of rbstudy's own fixed-step schemes (`GROUPS`: ``builtin``, ``published``), and
# that of every available engine scheme; each engine's group is the name of its adapter module
# (`ENGINES`: "rbstudy.engines.mujoco").
BUILTIN_GROUP = "builtin"
ENGINES_GROUP = "engines"


def _engine_of(name):
    return ENGINES[name].partition(":")[0].rpartition(".")[2]


def scheme_groups() -> dict[str, list[str]]:
    """group name -> the registered scheme names it stands for (available or not): one group
    per engine of `ENGINES`, ``engines`` for them all, and for rbstudy's own fixed-step
    schemes one per `GROUPS` (``builtin``, ``published``)."""
    groups = {
        group: [name for name, scheme in BUILTIN.items() if not scheme.adaptive and scheme.group == group]
        for group in GROUPS
    }
    groups[ENGINES_GROUP] = list(ENGINES)
    for name in ENGINES:
        groups.setdefault(_engine_of(name), []).append(name)
    return groups


def expand_groups(names: Iterable[str], option: str = "--schemes") -> list[str]:
    """``names`` (scheme or group names) with each group replaced by its available schemes,
    each scheme once, in the order given. A group none of whose schemes is available here
    raises `SchemeError` with why and the install command; ``engines`` takes whichever
    engines are installed."""
    groups = scheme_groups()
    expanded = []
    for name in names:
        if name not in groups:
            expanded.append(name)
            continue
        members = [member for member in groups[name] if isinstance(SCHEMES.find(member), Scheme)]
        if not members and name != ENGINES_GROUP:
            why = SCHEMES.find(groups[name][0])
            raise SchemeError(
                f"the group {name!r} has no scheme available here: {why.reason}", why.fix, key=option
            )
        expanded.extend(members)
    return list(dict.fromkeys(expanded))
