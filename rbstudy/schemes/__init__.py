"""The scheme registry: every module of this package that defines ``SCHEME`` is a scheme.

Adding a scheme means adding one file here; config validation, `rbstudy schemes`, the docs
table and the tests all read `SCHEMES`.
"""

import importlib
import pkgutil

from rbstudy.errors import SchemeError
from rbstudy.schemes._composition import ORDERS as COMPOSITION_ORDERS
from rbstudy.schemes._composition import stage_reach as composition_reach
from rbstudy.schemes._ready import get_ready
from rbstudy.schemes._registry import INVARIANTS, Option, Scheme

__all__ = ["SCHEMES", "INVARIANTS", "COMPOSITION_ORDERS", "Option", "Scheme", "composition_reach",
           "get_scheme", "get_ready"]


def _discover():
    found = {}
    for module_info in pkgutil.iter_modules(__path__):
        if module_info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{module_info.name}")
        scheme = module.SCHEME
        found[scheme.name] = scheme
    return dict(sorted(found.items()))


SCHEMES = _discover()


def get_scheme(name):
    """The registered scheme ``name``; an unknown name raises `SchemeError` listing the valid ones."""
    try:
        return SCHEMES[name]
    except (KeyError, TypeError):
        valid = ", ".join(SCHEMES)
        raise SchemeError(f"unknown scheme {name!r}", f"valid schemes: {valid}") from None
