"""Which config a study folder belongs to: the owner claim and the study identity.

`OWNER` (``.rbstudy-study``) in a study folder names the config whose study the folder
holds, by its resolved path and its text's SHA-256; the archive and every part carry the
same identity (`IDENTITY`). A sweep of another config with the same study name is refused
(`folder_claim`) unless forced, so two studies never mix in one folder.
"""

import hashlib
import os
import pathlib
import stat
from typing import Any

import netCDF4

from rbstudy.archive.files import write_text_atomic
from rbstudy.archive.hdf5 import HDF5_LOCK
from rbstudy.archive.ids import IDENTITY, study_identity
from rbstudy.archive.parts import PART_SUFFIX, UNREADABLE_PART, part_attributes
from rbstudy.errors import ConfigError
from rbstudy.inputs.reader import open_regular_file

__all__ = ["OWNER", "claim_folder", "folder_claim"]


# The file of a study folder that names the config (its file's resolved path and its text's
# SHA-256) whose study the folder holds: another config of the same name would replace its
# archive and parts.
OWNER = ".rbstudy-study"


# Bytes of an owner record read at most: a resolved path and a digest.
_OWNER_BYTES = 2**13


def _parsed_identity(text):
    """The (path, digest) of `study_identity` written one a line, or None where ``text`` is
    no such thing (empty, garbled, not text)."""
    lines = text.split("\n") if isinstance(text, str) else []
    if len(lines) < 2 or not lines[0] or len(lines[1]) != 64 or set(lines[1]) - set("0123456789abcdef"):
        return None
    return lines[0], lines[1]


def _regular_file(path):
    """Whether ``path`` is (or links to) a regular file: a FIFO would hang its reader and a
    device (/dev/zero) never end, so neither is opened."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):
        return False


def _recorded_identity(record):
    """The identity `OWNER` at ``record`` names, or None: absent, unreadable, not a regular
    file (`open_regular_file`: a FIFO or /dev/zero is never read), empty or garbled; read
    at most `_OWNER_BYTES`."""
    try:
        with open_regular_file(record) as file:
            text = file.read(_OWNER_BYTES + 1)
    except OSError:
        return None
    if len(text) > _OWNER_BYTES:
        return None
    try:
        return _parsed_identity(text.decode())
    except UnicodeDecodeError:
        return None


def _results_identity(path):
    """The identity the archive or part at ``path`` names (`IDENTITY`), or None. An archive
    from before that attribute is taken for the config it stores: its recorded
    ``config_path`` (resolved from here) and the digest of its ``config`` text, which is the
    file's unless ``--set`` changed it; a part from before names nobody."""
    if not _regular_file(path):
        return None
    try:
        with HDF5_LOCK, netCDF4.Dataset(path) as nc:
            attrs = {
                name: nc.getncattr(name)
                for name in (IDENTITY, "config", "config_path")
                if name in nc.ncattrs()
            }
    except (OSError, RuntimeError, UnicodeDecodeError):
        return None
    if IDENTITY in attrs:
        return _parsed_identity(attrs[IDENTITY])
    config, config_path = attrs.get("config"), attrs.get("config_path")
    if not isinstance(config, str) or not isinstance(config_path, str) or not config_path:
        return None
    return str(pathlib.Path(config_path).resolve()), hashlib.sha256(config.encode()).hexdigest()


def _part_files(folder):
    """The part files in ``folder``'s parts, of this version and of those that wrote netCDF."""
    parts = pathlib.Path(folder) / "parts"
    return sorted([*parts.glob(f"*{PART_SUFFIX}"), *parts.glob("*.nc")])


def _part_identity(path):
    """The identity the part at ``path`` names, or None (a damaged part names nobody)."""
    if path.suffix != PART_SUFFIX:
        return _results_identity(path)  # netCDF, as earlier versions wrote parts
    if not _regular_file(path):
        return None
    try:
        return _parsed_identity(part_attributes(path)["identity"])
    except UNREADABLE_PART:
        return None


def _results_owner(folder, study):
    """The identity of another config named by ``folder``'s archive or parts, or None when
    none names one, or one names ``study`` (parts of every age: the file edited since some
    of them were written is still the same study)."""
    mine, other = set(study_identity(study)), None
    for path in [folder / f"{study.name}.nc", *_part_files(folder)]:
        identity = _results_identity(path) if path.parent == folder else _part_identity(path)
        if identity is not None and set(identity) & mine:
            return None
        other = other or identity
    return other


def folder_claim(root: str | os.PathLike[str], study: Any, force: bool = False) -> str | None:
    """Whether ``<root>/<study.name>`` may take ``study``'s results; reads only.

    A study folder belongs to the config that made it (`OWNER`: its file and its text's
    digest; where that record is missing or is no record, the config its archive and parts
    name, `IDENTITY`). Edited, that file is still the same study: its rerun resumes or
    rebuilds as it always has; so is the same text moved or copied to another file. A new
    folder, or one whose files name no config (from before they did), takes any. A folder of
    another config of the same name is refused (a `ConfigError` naming both files), unless
    ``force``: then the line saying what the run replaces is returned; else None.
    """
    folder = pathlib.Path(root) / study.name
    owner = _recorded_identity(folder / OWNER) or _results_owner(folder, study)
    if owner is None or set(owner) & set(study_identity(study)):
        return None
    if not force:
        raise ConfigError(
            f"{folder} holds the study of another config of this name, {owner[0]}",
            "give this study another name or another --out (--force replaces that study)",
            source=study.path,
            key="name",
        )
    kept = len(_part_files(folder))
    archive = "its archive and " if (folder / f"{study.name}.nc").exists() else ""
    return (
        f"{study.name}: --force replaces the study of {owner[0]} in {folder} ({archive}"
        f"{kept} kept part{'' if kept == 1 else 's'})"
    )


def claim_folder(folder: str | os.PathLike[str], study: Any) -> None:
    """Record ``study``'s config as the one whose study ``folder`` holds (`folder_claim`
    must have let it). A rename replaces whatever is in the record's place but a folder,
    which is not rbstudy's to remove: then the archive and the parts name the study alone."""
    identity = study_identity(study)
    path = pathlib.Path(folder) / OWNER
    if path.is_dir() and not path.is_symlink():
        return
    if _recorded_identity(path) != identity:
        write_text_atomic("\n".join(identity) + "\n", path)
