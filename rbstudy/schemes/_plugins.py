"""Schemes from other packages: the entry points of the group ``rbstudy.schemes``.

A package registers a scheme by naming a `Scheme` object under the scheme's name in its
metadata (docs/extending.md):

    [project.entry-points."rbstudy.schemes"]
    semi_implicit = "rbstudy_semi_implicit.compiled:SCHEME"

rbstudy registers its own adapters of other engines (`rbstudy.engines`) the same way, in its
own pyproject.toml (`ENGINES`), so that every module the registry loads is named in package
metadata, where the layer test reads it too. `load_engines` loads rbstudy's own entries,
`load_plugins` the other packages'; the registry calls each only when it needs a name it may
give. A plug-in that cannot be loaded here never stops rbstudy: it is listed as
unavailable, with why and what to do (`Unavailable`). A package whose scheme needs something
absent (an engine's Python bindings) says so by raising `SchemeUnavailable` when its module
is imported, with the install command as the fix.

Other packages' code runs in this process only once it has shown it can: each plug-in
module is first imported in a child process (`_probe`), and one whose import does not finish
within `IMPORT_SECONDS` or ends the process (``os._exit``) is listed unavailable and never
imported here. The child is a fork of this process where that is safe (no other thread),
which costs milliseconds, else a fresh interpreter. A module that raises, even
``SystemExit``, is imported here and caught. A plug-in's scheme runs through `Guarded`: an
exception from its step, or a status that is none of rbstudy's codes, ends the batch with
one `RbstudyError` naming the scheme and its package, not as a bug of rbstudy.

Each plug-in scheme carries a digest of its package's sources (`Scheme.code_digest`,
`rbstudy.numerics.sources.package_digest`), which enters the ids of its batches: parts
computed by older code of the plug-in are never reused, as rbstudy's own source digest
ensures for the built-in schemes. A plug-in's module must not read the registry when it is
imported (`BUILTIN` is there for that): imported first by a user, it would find itself
half-initialised and be listed unavailable.
"""

import contextlib
import importlib
import importlib.metadata
import os
import pathlib
import select
import signal
import sys
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rbstudy.errors import RbstudyError, one_line
from rbstudy.numerics.driver import StatusError, check_statuses
from rbstudy.numerics.sources import package_digest
from rbstudy.numerics.state import Result
from rbstudy.schemes._registry import Scheme

__all__ = [
    "GROUP",
    "ENGINES",
    "IMPORT_SECONDS",
    "SchemeUnavailable",
    "Unavailable",
    "Guarded",
    "load_engines",
    "load_plugins",
]

GROUP = "rbstudy.schemes"
# The distribution whose entries of `GROUP` are rbstudy's own (`ENGINES`), not plug-ins.
DISTRIBUTION = "rbstudy"
# The source tree's project file, when rbstudy runs from one (an editable install, a checkout
# on the path); an installed wheel has none beside its package.
_PYPROJECT = pathlib.Path(__file__).resolve().parents[2] / "pyproject.toml"


def _own_entries():
    """rbstudy's own entries of `GROUP`, name -> "module:attribute" in the order of the names
    (as setuptools writes them into the metadata, and as the plug-ins are listed): those of
    the source tree's pyproject.toml when rbstudy runs from one, else those of its installed
    metadata. An editable install's metadata is written by ``pip install -e .`` and keeps the
    entry points of that moment: the project file is what the code beside it declares now."""
    try:
        # Python 3.11 on; on 3.10 a source tree reads the metadata as well (mypy checks for
        # 3.10, whose standard library has no tomllib: the ImportError below is that case)
        import tomllib  # type: ignore[import-not-found, unused-ignore]

        project = tomllib.loads(_PYPROJECT.read_text())["project"]
        if project["name"] == DISTRIBUTION:
            return dict(sorted(project["entry-points"][GROUP].items()))
    except (ImportError, OSError, ValueError, KeyError):  # no source tree: installed
        pass
    installed = importlib.metadata.distribution(DISTRIBUTION).entry_points
    return dict(sorted((point.name, point.value) for point in installed.select(group=GROUP)))


# rbstudy's own adapters of other engines (`rbstudy.engines`), loaded as plug-ins are:
# name -> "module:attribute". Each names its engine and version in its `origin` and
# `code_digest`, so that another version of the engine never reuses a part.
ENGINES = _own_entries()
# A plug-in module whose import takes longer is taken for hung and listed unavailable.
# Importing a heavy dependency (an engine's bindings, a numerical framework) from a cold disk
# takes seconds; rbstudy's own import with numba, far less.
IMPORT_SECONDS = 30.0
# After this long, the plug-in being imported is named on stderr: a slow import is seen as
# such, not taken for a frozen command.
NOTICE_SECONDS = 2.0
# The probing child in a fresh interpreter (`_start`): it imports the modules given after the
# number of the file descriptor it writes its bytes to (`_import_each`).
_CHILD = """
import sys
from rbstudy.schemes._plugins import _import_each
_import_each(sys.argv[2:], int(sys.argv[1]))
"""


class SchemeUnavailable(ImportError):  # noqa: N818 (read as "raise SchemeUnavailable(...)")
    """Raised by a plug-in's module when its scheme cannot run here: ``reason`` says why,
    ``fix`` what to run (``pip install "mujoco>=4.0"``)."""

    def __init__(self, reason: str, fix: str) -> None:
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


class Guarded:
    """A plug-in scheme's entry point (`rbstudy.numerics.driver`'s contract), run so that what
    goes wrong in it is told as the plug-in's fault: an exception, or a status that is none of
    rbstudy's codes, becomes one `RbstudyError` naming the scheme and its package. Its other
    attributes (`is_cached`, `whole_batch`, numba's `signatures`) are the entry point's."""

    def __init__(self, entry: Callable[..., Any], name: str, origin: str) -> None:
        self._entry, self._name, self._origin = entry, name, origin

    def __getattr__(self, attribute: str) -> Any:
        if attribute.startswith("_"):  # its own (copy and pickle ask before they exist)
            raise AttributeError(attribute)
        return getattr(self._entry, attribute)

    def __call__(
        self,
        start: int,
        stop: int,
        state0: np.ndarray,
        params: np.ndarray,
        options: np.ndarray,
        h: float,
        n_steps: int,
        every: int,
        drift_bound: float,
        samples: np.ndarray,
        results: np.ndarray,
        halt: np.ndarray,
        clock: float | None = None,
    ) -> None:
        try:
            self._entry(
                start,
                stop,
                state0,
                params,
                options,
                h,
                n_steps,
                every,
                drift_bound,
                samples,
                results,
                halt,
                clock,
            )
            codes = results[start:stop, Result["status"]]
            check_statuses(codes[~np.isnan(codes)])  # NaN: a body a halt left unfinished
        except StatusError as error:
            raise self._failure(f"its step {error}") from error
        except Exception as error:  # noqa: BLE001 (whatever a plug-in raises is its own)
            raise self._failure(f"its step raised {type(error).__name__}: {one_line(error)}") from error

    def _failure(self, what):
        return RbstudyError(
            f"scheme {self._name!r} (plug-in: {self._origin}) failed: {what}; "
            f"fix or report it in {_package(self._origin)}, or leave the "
            "scheme out"
        )


def _own(entry_point):
    """An engine adapter of rbstudy's own (`ENGINES`)."""
    return entry_point.module.startswith("rbstudy.")


def _origin(entry_point):
    if _own(entry_point):
        return "rbstudy"
    dist = getattr(entry_point, "dist", None)
    return f"{dist.name} {dist.version}" if dist is not None else entry_point.value


def _package(origin):
    """The package of an origin ("rbstudy-semi-implicit 0.1.0")."""
    return origin.split()[0]


def _load(entry_point, taken, refusal=None):
    """The `Scheme` of one entry point (with its code digest and origin), or why not:
    ``refusal`` is why its module is not to be imported here (`_probe`)."""
    origin = _origin(entry_point)
    package = _package(origin)
    if entry_point.name in taken:
        return Unavailable(
            entry_point.name,
            f"the name is taken by {taken[entry_point.name]}",
            f"rename the scheme in {package}",
            origin,
        )
    if refusal:
        return Unavailable(entry_point.name, refusal, f"reinstall or fix {package}", origin)
    try:
        scheme = entry_point.load()
        digest = None if _own(entry_point) else package_digest(entry_point.module)
    except SchemeUnavailable as error:
        return Unavailable(entry_point.name, error.reason, error.fix, origin)
    except SystemExit as error:  # a module that ends the program must not end rbstudy
        return Unavailable(
            entry_point.name,
            f"its import called sys.exit({error.code!r})",
            f"reinstall or fix {package}",
            origin,
        )
    except Exception as error:  # a plug-in's bug must not stop the other schemes
        return Unavailable(
            entry_point.name, f"cannot be loaded ({one_line(error)})", f"reinstall or fix {package}", origin
        )
    if not isinstance(scheme, Scheme):
        return Unavailable(
            entry_point.name,
            f"{entry_point.value} is a {type(scheme).__name__}, not a Scheme",
            f"point the entry point at a rbstudy.schemes.Scheme in {package}",
            origin,
        )
    if scheme.name != entry_point.name:
        return Unavailable(
            entry_point.name,
            f"{entry_point.value} is the scheme {scheme.name!r}",
            "name the entry point as its scheme",
            origin,
        )
    if _own(entry_point):  # rbstudy's source digest covers the adapter; it names the engine
        return scheme
    return replace(
        scheme,
        origin=origin,
        code_digest=digest,
        run_bodies_inplace=Guarded(scheme.run_bodies_inplace, scheme.name, origin),
    )


def _load_all(entry_points, taken, refused):
    """(name -> `Scheme`, name -> `Unavailable`) of ``entry_points``; ``taken``: name -> who
    holds it already; ``refused``: name -> why its module is not to be imported."""
    taken = dict(taken)
    found, unavailable = {}, {}
    for entry_point in entry_points:
        loaded = _load(entry_point, taken, refused.get(entry_point.name))
        if isinstance(loaded, Unavailable):
            unavailable[loaded.name] = loaded
        else:
            found[loaded.name] = loaded
            taken[loaded.name] = loaded.origin
    return found, unavailable


def load_engines(builtin: Iterable[str]) -> tuple[dict[str, Scheme], dict[str, Unavailable]]:
    """rbstudy's adapters of other engines (`ENGINES`): (name -> `Scheme`, name ->
    `Unavailable`), imported here (rbstudy's own code, whose engine may be absent).
    ``builtin``: rbstudy's own schemes."""
    return _load_all(
        [importlib.metadata.EntryPoint(name, value, GROUP) for name, value in ENGINES.items()],
        {name: "rbstudy's own scheme" for name in builtin},
        {},
    )


def load_plugins(builtin: Iterable[str]) -> tuple[dict[str, Scheme], dict[str, Unavailable]]:
    """The plug-ins' schemes of this environment: (name -> `Scheme`, name -> `Unavailable`).
    ``builtin`` are rbstudy's own schemes, whose names, and those of `ENGINES`, a plug-in may
    not take. Each module is imported in a child process first (`_probe`)."""
    taken = {
        **{name: "rbstudy's own scheme" for name in builtin},
        **{name: "rbstudy's adapter of an engine" for name in ENGINES},
    }
    entry_points = sorted(
        (
            point
            for point in importlib.metadata.entry_points(group=GROUP)
            if getattr(point.dist, "name", None) != DISTRIBUTION
        ),
        key=lambda point: point.name,
    )
    return _load_all(
        entry_points, taken, _probe([point for point in entry_points if point.name not in taken])
    )


def _probe(entry_points):
    """name -> why not, for each of ``entry_points`` whose module, imported in a child
    process, did not finish within `IMPORT_SECONDS` or ended the process. A module already
    imported here is not probed again. A child that ends or is stopped is followed by another
    for the modules after its own."""
    first = {}  # module -> the first entry point in it: the plug-in the notice names
    for point in entry_points:
        if point.module not in sys.modules:
            first.setdefault(point.module, point)
    modules, refused = list(first), {}
    while modules:
        read_end, pid = _start(modules)
        answer, done = b".", 0
        try:
            for module in modules:
                answer = _answer(read_end, NOTICE_SECONDS)
                if answer is None:  # a slow import: say which, then wait for the rest
                    print(
                        f"rbstudy: loading plug-in {first[module].name} from "
                        f"{_package(_origin(first[module]))}...",
                        file=sys.stderr,
                        flush=True,
                    )
                    answer = _answer(read_end, IMPORT_SECONDS - NOTICE_SECONDS)
                if answer != b".":
                    break
                done += 1
        finally:
            os.close(read_end)
            code = _end(pid, kill=answer != b"")
        if done < len(modules):
            refused[modules[done]] = (
                f"its import did not finish within {IMPORT_SECONDS:g} s"
                if answer is None
                else f"its import ended the process (exit code {code})"
                if code >= 0
                else f"its import ended the process (signal {-code})"
            )
        modules = modules[done + 1 :]
    return {point.name: refused[point.module] for point in entry_points if point.module in refused}


def _import_each(modules, out):
    """The probing child: import each of ``modules``, and write a byte to the file
    descriptor ``out`` after each, whatever its outcome (this process, importing it again,
    tells how it failed)."""
    for module in modules:
        with contextlib.suppress(BaseException):
            importlib.import_module(module)
        os.write(out, b".")


def _start(modules):
    """A child process that imports ``modules`` (`_import_each`): (the read end of the pipe
    it writes to, its pid). Nothing it prints reaches this process's output."""
    read_end, write_end = os.pipe()
    try:
        # a fork copies this process at once, but not the other threads, which may hold
        # locks the child would wait for: with threads, a fresh interpreter (slower to start)
        if hasattr(os, "fork") and threading.active_count() == 1:
            pid = os.fork()
            if pid == 0:
                try:
                    os.close(read_end)
                    silent = os.open(os.devnull, os.O_WRONLY)
                    os.dup2(silent, 1)  # the descriptors: sys.stdout may be a test's buffer
                    os.dup2(silent, 2)
                    _import_each(modules, write_end)
                finally:
                    os._exit(0)  # never this process's code after the fork, nor its teardown
            return read_end, pid
        out = write_end + 1  # the child's copy of the write end (a number of its own)
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(path for path in sys.path if path),
            "PYTHONWARNINGS": "ignore",
        }
        pid = os.posix_spawn(
            sys.executable,
            [sys.executable, "-c", _CHILD, str(out), *modules],
            env,
            file_actions=[
                (os.POSIX_SPAWN_DUP2, write_end, out),
                (os.POSIX_SPAWN_OPEN, 1, os.devnull, os.O_WRONLY, 0),
                (os.POSIX_SPAWN_OPEN, 2, os.devnull, os.O_WRONLY, 0),
            ],
        )
        return read_end, pid
    finally:
        os.close(write_end)


def _answer(read_end, seconds):
    """The child's next byte (b"" when it has ended), or None when none came in
    ``seconds``."""
    ready, _, _ = select.select([read_end], [], [], seconds)
    return os.read(read_end, 1) if ready else None


def _end(pid, kill):
    """Wait for the child ``pid``, stopped first when ``kill``; its exit code (-N: signal N)."""
    if kill:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
