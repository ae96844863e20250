"""Errors a user can cause. The CLI prints them in one line and exits non-zero.

Every message names where the problem is (file, key path), the value received and what is
expected, so that the user can fix the input without reading code.
"""

__all__ = ["RbstudyError", "SceneError", "ConfigError", "SchemeError"]


class RbstudyError(Exception):
    """Base class of all expected, user-caused failures."""


class SceneError(RbstudyError):
    """A scene description is malformed or non-physical."""


class ConfigError(RbstudyError):
    """A study configuration is malformed."""


class SchemeError(RbstudyError):
    """An unknown scheme, an unknown scheme option, or an option value out of range."""
