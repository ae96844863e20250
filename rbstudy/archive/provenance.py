"""What an archive records of where it came from: its global attributes.

The config's text and path, the study's identity, the versions of rbstudy (with its git
commit where there is one) and of the libraries that made the numbers, the platform, and a
CF ``history`` line (`global_attrs`).
"""

import datetime
import pathlib
import platform
import shlex
import subprocess
import sys
from importlib import metadata
from typing import Any

from rbstudy.archive.ids import IDENTITY, batches_digest, study_identity

__all__ = ["global_attrs", "source_text", "utc_now"]


_DEPENDENCIES = (
    "numpy",
    "scipy",
    "numba",
    "xarray",
    "netCDF4",
    "dask",
    "distributed",
    "matplotlib",
    "PyYAML",
)


# How long git may take to name the checkout's commit (it answers in milliseconds; a hung
# network file system must not hold the sweep).
_GIT_SECONDS = 5


def _versions():
    found = {}
    for name in ("rbstudy",) + _DEPENDENCIES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def source_text(version: str) -> str:
    """``rbstudy <version>``, with the commit of the checkout the package runs from
    (``rbstudy 0.4.0 (commit abc1234)``, ``..., modified)`` when its tracked files differ
    from it): an editable install's version names no code, its commit does. Just the
    version where the package is no checkout or git cannot tell."""
    checkout = pathlib.Path(__file__).resolve().parents[2]
    if not (checkout / ".git").exists():  # a .git file in a worktree: exists() too
        return f"rbstudy {version}"
    try:
        commit, changes = (
            subprocess.run(
                ["git", "-C", str(checkout), *arguments],
                capture_output=True,
                text=True,
                check=True,
                timeout=_GIT_SECONDS,
            ).stdout.strip()
            for arguments in (
                ["rev-parse", "--short", "HEAD"],
                ["status", "--porcelain", "--untracked-files=no"],
            )
        )
    except (OSError, subprocess.SubprocessError):
        return f"rbstudy {version}"
    return f"rbstudy {version} (commit {commit}{', modified' if changes else ''})"


def utc_now() -> str:
    """Now, in UTC, as ISO 8601 to the second."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def global_attrs(study: Any, command: str | None = None, started: str | None = None) -> dict[str, Any]:
    """The global attributes: CF conventions, provenance, the config text (with the ``--set``
    overrides applied) and the overrides, one a line (empty without)."""
    versions = _versions()
    command = command or shlex.join(["rbstudy"] + sys.argv[1:])  # `--set 'k=[1, 2]'` quoted
    history = f"{started or utc_now()} {command} (started)\n{utc_now()} {command} (finished)"
    return {
        "Conventions": "CF-1.11",
        "title": study.title,
        "institution": "rbstudy user",
        "source": source_text(versions["rbstudy"]),
        "history": history,
        "comment": "Rigid-body integrator study; errors are measured against the reference "
        "named per case by the variable `reference`.",
        "study": study.name,
        "batches": batches_digest(study.batches),
        "accuracy_bound": study.accuracy_bound,
        "config": study.archived_text,
        "config_path": study.path,
        IDENTITY: "\n".join(study_identity(study)),
        "overrides": "\n".join(study.overrides),
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "versions": "; ".join(f"{k} {v}" for k, v in versions.items()),
    }
