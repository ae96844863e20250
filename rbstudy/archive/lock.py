"""The study lock: one sweep at a time writes a study's folder."""

import os
import pathlib

from filelock import AcquireReturnProxy, FileLock, Timeout

from rbstudy.archive.files import unwritable
from rbstudy.errors import RbstudyError

__all__ = ["PID_FILE", "StudyBusy", "study_lock"]


# Where the sweep that holds a study's lock writes its pid, for a second sweep to name it.
PID_FILE = ".lock.pid"


class StudyBusy(RbstudyError):
    """Another sweep holds the study's lock: the folder is that sweep's, even if this one
    made it an instant before."""


def study_lock(folder: pathlib.Path) -> AcquireReturnProxy:
    """Take ``folder/.lock`` for the sweep and return it, a context manager whose exit
    releases it; a second sweep of the same study refuses at once, naming the holder's pid,
    and so does a folder that cannot be written (`rbstudy.archive.files.UnwritableFolder`,
    or the full disk's error).

    The lock is the system's (``flock``; ``msvcrt.locking`` on Windows) through `filelock`:
    the system releases it when the process dies, so a killed sweep never leaves a stale
    lock. The holder writes its pid beside it, in ``.lock.pid``: a locked file cannot be read
    on Windows, and filelock 3 empties the lock file at each attempt to take it.
    """
    lock = FileLock(folder / ".lock", timeout=0)
    try:
        held = lock.acquire()
    except Timeout:
        raise StudyBusy(
            f"{folder}: another rbstudy sweep is writing this study (pid "
            f"{_holder(folder)}); wait for it to finish or use another "
            "--out"
        ) from None
    except OSError as error:
        raise unwritable(folder, error) from None
    try:
        pid_file = os.open(folder / PID_FILE, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.write(pid_file, str(os.getpid()).encode())
        finally:
            os.close(pid_file)
    except OSError as error:  # a full disk: the pid needs a block
        lock.release()
        raise unwritable(folder, error) from None
    return held


def _holder(folder):
    """The pid of the sweep that holds ``folder``'s lock, as it wrote it (or "unknown")."""
    try:
        return (folder / PID_FILE).read_text().strip() or "unknown"
    except OSError:
        return "unknown"
