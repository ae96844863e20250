"""The scheme registry: rbstudy's own schemes and those other packages register.

Every module of this package that defines ``SCHEME`` is one of rbstudy's schemes: adding a
scheme means adding one file here; config validation, `rbstudy schemes`, the docs table and
the tests all read `SCHEMES`. Other packages add theirs through the entry-point group
``rbstudy.schemes`` (`rbstudy.schemes._plugins`, docs/extending.md); those that cannot run
here are listed by `unavailable_schemes`, with why and the fix.

The plug-ins are loaded the first time the registry is read, not when this package is
imported: a plug-in's module imports this package for `Scheme`, and must find it complete.
"""

import importlib
import pkgutil
import threading
from collections.abc import Mapping

from rbstudy.errors import SchemeError
from rbstudy.schemes._composition import ORDERS as COMPOSITION_ORDERS
from rbstudy.schemes._composition import stage_reach as composition_reach
from rbstudy.schemes._plugins import SchemeUnavailable, Unavailable, load_plugins
from rbstudy.schemes._ready import get_ready
from rbstudy.schemes._registry import INVARIANTS, Option, Scheme

__all__ = ["SCHEMES", "BUILTIN", "INVARIANTS", "COMPOSITION_ORDERS", "Option", "Scheme",
           "SchemeUnavailable", "Unavailable", "composition_reach", "get_scheme", "get_ready",
           "unavailable_schemes"]


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
    """name -> `Scheme`: rbstudy's own, then the engine adapters' and plug-ins', loaded on
    the first reading. Other threads wait for that loading; a plug-in that reads the
    registry while it is loaded (the same thread) sees rbstudy's own schemes."""

    def __init__(self, builtin):
        self._builtin = builtin
        self._all = None
        self._unavailable = {}
        self._lock = threading.RLock()
        self._loading = False

    def _schemes(self):
        if self._all is not None:
            return self._all
        with self._lock:
            if self._all is None:
                if self._loading:
                    return self._builtin
                self._loading = True
                try:
                    plugins, self._unavailable = load_plugins(self._builtin)
                finally:
                    self._loading = False
                self._all = {**self._builtin, **plugins}
        return self._all

    def unavailable(self):
        self._schemes()
        return self._unavailable

    def __getitem__(self, name):
        return self._schemes()[name]

    def __iter__(self):
        return iter(self._schemes())

    def __len__(self):
        return len(self._schemes())


BUILTIN = _discover()
SCHEMES = _Registry(BUILTIN)


def unavailable_schemes():
    """name -> `Unavailable`: the registered schemes that cannot run here."""
    return SCHEMES.unavailable()


def get_scheme(name):
    """The registered scheme ``name``; an unknown name raises `SchemeError` listing the valid
    ones, an unavailable one says why and how to make it available."""
    try:
        return SCHEMES[name]
    except (KeyError, TypeError):
        pass
    if isinstance(name, str) and name in unavailable_schemes():
        missing = unavailable_schemes()[name]
        raise SchemeError(f"scheme {name!r} ({missing.origin}) is not available here: "
                          f"{missing.reason}", missing.fix) from None
    valid = ", ".join(SCHEMES)
    raise SchemeError(f"unknown scheme {name!r}", f"valid schemes: {valid}") from None
