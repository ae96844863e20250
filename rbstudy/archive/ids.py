"""Canonical ids of what a study's results are made of.

A batch's id (`rbstudy.pipeline.batches`) and the digests that bind an archive or a step
search to its batches are SHA-256 hashes of canonical JSON (`canonical_id`: keys sorted,
numbers normalised so that 0.1 and 1e-1 hash alike). `SCHEMA_VERSION` goes into every id,
so a bump renews them all (see its comment for what that costs). A study's identity
(`study_identity`: its config file and text) says whose results a folder holds.
"""

import hashlib
import json
import pathlib
from collections.abc import Iterable
from typing import Any

__all__ = [
    "IDENTITY",
    "ID_LENGTH",
    "SCHEMA_VERSION",
    "batches_digest",
    "canonical_id",
    "ids_digest",
    "study_identity",
]


# Bumped whenever what a part file holds changes, so that old parts are never reused. It is
# hashed into every archive's `batches` attribute too, which verify recomputes: a bump makes
# every archive written before it fail verify. The parts' move from netCDF to .npz needed
# none: a part of another format has another name, and is never found.
SCHEMA_VERSION = 2


# Hex digits of a batch id's hash: 64 bits, no collision among any realistic set of batches.
ID_LENGTH = 16


def _normalised(value):
    """JSON-ready copy with every number a float, so that 1 and 1.0 hash alike."""
    if isinstance(value, dict):
        return {str(k): _normalised(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_normalised(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    try:
        return float(value)
    except (OverflowError, TypeError, ValueError):  # refused later, with its key, by the reader
        return repr(value)


def canonical_id(payload: Any) -> str:
    """A short stable hash of ``payload``: canonical JSON (sorted keys, numbers as floats) plus
    `SCHEMA_VERSION`."""
    text = json.dumps(
        {"schema": SCHEMA_VERSION, "payload": _normalised(payload)}, sort_keys=True, separators=(",", ":")
    )
    return hashlib.sha256(text.encode()).hexdigest()[:ID_LENGTH]


def batches_digest(batches: Iterable[Any]) -> str:
    """One id for a whole study's batches: an archive built from exactly these is current."""
    return ids_digest([batch.id for batch in batches])


def ids_digest(ids: Iterable[str]) -> str:
    """`batches_digest` of the batches of ids ``ids``, in order."""
    return canonical_id(list(ids))


# The global attribute of the archive (and what each part says) that names the config of its
# study, as the study folder's owner record does (`rbstudy.archive.owner.OWNER`, two lines):
# the results identify their study without the record.
IDENTITY = "config_identity"


def study_identity(study: Any) -> tuple[str, str]:
    """Who ``study`` is to its folder (`rbstudy.archive.owner.OWNER`, `IDENTITY`): its config
    file's resolved path and the SHA-256 of the config's text. Two identities are one study
    when either matches: the same file edited, or the same text moved to another file."""
    return (str(pathlib.Path(study.path).resolve()), hashlib.sha256(study.text.encode()).hexdigest())
