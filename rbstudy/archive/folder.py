"""A study's folder on disk, as one object: `StudyFolder`.

``<root>/<study>/`` holds ``<study>.nc`` (the archive; ``<study>.zarr``, a zarr store, when
the study's ``output_format`` is "zarr": `FORMATS`), ``parts/<batch-id>.npz`` (one finished
batch each, with its digest beside it; where workers write a zarr store's regions, the
working store ``parts/<study>.zarr`` and a mark ``parts/<batch-id>.region`` a batch),
``study.yaml`` (the resolved config), the owner record (`rbstudy.archive.owner.OWNER`), the
lock and, while a step search runs, its working file ``search/steps.nc`` (`SEARCH_FILE`).
The sweep and the step search reach every one of them through a `StudyFolder` alone: where a
file lies, how it is named, checked, locked, claimed, written and removed is said here and in
the modules below it, never by the sweep.

The study object is read, not imported: a `rbstudy.pipeline.config.StudyConfig` (its
``name``, ``output_format``, ``batches``, each with ``id`` and ``cases``, and what
`rbstudy.archive.owner` and `rbstudy.archive.writer` read of it). Which format the archive
has is decided here, once: the sweep asks the folder for its ``archive`` and its ``writer``.
"""

from __future__ import annotations

import contextlib
import functools
import os
import pathlib
import shutil
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Any, NamedTuple

import netCDF4

from rbstudy.archive.checksums import verify_archive
from rbstudy.archive.files import (
    WRITE_REFUSALS,
    make_folders,
    remove_folders,
    unwritable,
    write_dataset_atomic,
    write_text_atomic,
)
from rbstudy.archive.hdf5 import HDF5_LOCK
from rbstudy.archive.ids import batches_digest
from rbstudy.archive.layout import FORMATS, SEARCH_GROUP, Layout
from rbstudy.archive.load import open_results, read_group
from rbstudy.archive.lock import study_lock
from rbstudy.archive.owner import claim_folder, folder_claim
from rbstudy.archive.parts import PART_SUFFIX, SIDECAR_SUFFIX, PartTarget, part_complete, sealed, sidecar
from rbstudy.archive.provenance import global_attrs
from rbstudy.archive.rewrite import put_group, refresh_description
from rbstudy.archive.writer import ArchiveWriter
from rbstudy.archive.zarr_integrity import verify_store
from rbstudy.archive.zarr_regions import (
    MARK_SUFFIX,
    RegionTarget,
    finish_regions,
    mark_generation,
    open_working,
    region_complete,
    remove_marks,
    working_generation,
)
from rbstudy.archive.zarr_store import consolidate_store, refresh_store_description, store_attribute
from rbstudy.errors import RbstudyError, one_line

if TYPE_CHECKING:
    import xarray as xr
    from filelock import AcquireReturnProxy

__all__ = ["ArchiveState", "SEARCH_FILE", "StudyFolder"]

# The step search's working file, in the study folder, until the archive holds the search.
SEARCH_FILE = pathlib.Path("search") / "steps.nc"


class ArchiveState(NamedTuple):
    """What a folder's archive is to its study: ``kind`` "absent", "outdated" (another
    config or code: its ``batches`` differ), "damaged" (``problems``: what no longer matches
    its checksum, `rbstudy.archive.checksums`) or "current" (a rerun has nothing to do)."""

    kind: str
    problems: tuple[str, ...] = ()

    @property
    def current(self) -> bool:
        return self.kind == "current"


class StudyFolder:
    """The folder ``path`` of ``study``: its archive ``<name>.nc`` or ``<name>.zarr``
    (``name``: the study's; `archive`), parts or marks and the working store, lock, owner
    record, config and step search. Making the object touches nothing on disk."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        study: Any,
        name: str | None = None,
        unit_lock: Callable[[str], AbstractContextManager[Any]] | None = None,
    ) -> None:
        self.study, self.path = study, pathlib.Path(path)
        self.name = study.name if name is None else name
        self.unit_lock = unit_lock
        self.made: list[pathlib.Path] = []  # the folders `make` made, outermost first
        self.generation: str | None = None  # of the working store the workers write (`writer`), once open

    @classmethod
    def of(
        cls,
        root: str | os.PathLike[str],
        study: Any,
        unit_lock: Callable[[str], AbstractContextManager[Any]] | None = None,
    ) -> StudyFolder:
        """The folder of ``study`` under the results folder ``root``: ``<root>/<study.name>``;
        ``unit_lock``: where the batches run on a cluster's workers (``--workers``,
        ``--cluster``, ``--scheduler``), which write a zarr store's regions themselves, the
        lock of one of its units across the cluster, a function of the lock's name."""
        return cls(pathlib.Path(root) / study.name, study, unit_lock=unit_lock)

    @functools.cached_property
    def layout(self) -> Layout:
        """The netCDF `Layout` of the study's parts and archive."""
        return Layout.of(self.study)

    @property
    def archive(self) -> pathlib.Path:
        return self.path / f"{self.name}{FORMATS[self.format]}"

    @property
    def format(self) -> str:
        """The archive's format, a key of `FORMATS` (the study's; read when it is asked: the
        step search's folder of its working file alone has no study)."""
        return self.study.output_format

    @property
    def zarr(self) -> bool:
        return self.format == "zarr"

    @property
    def regions(self) -> bool:
        """Whether the workers that compute the batches write a zarr store, each its region
        (`rbstudy.archive.zarr_regions`), a unit at a time under ``unit_lock``: no part passes
        through one writer."""
        return self.unit_lock is not None and self.zarr

    @property
    def parts(self) -> pathlib.Path:
        return self.path / "parts"

    @property
    def job_logs(self) -> pathlib.Path:
        """Where a cluster's batch jobs write their output (else SLURM writes slurm-<id>.out
        where the sweep was started): among the parts, kept with them when a run fails and
        removed with them when it succeeds."""
        return self.parts / "jobs"

    @property
    def search_file(self) -> pathlib.Path:
        return self.path / SEARCH_FILE

    def part_path(self, batch_id: str) -> pathlib.Path:
        """Where a batch's part is, or its mark where the workers write the store's regions."""
        return self.parts / f"{batch_id}{MARK_SUFFIX if self.regions else PART_SUFFIX}"

    @property
    def working_store(self) -> pathlib.Path:
        """The zarr store the workers write their regions to, until it is sealed."""
        return self.parts / f"{self.name}{FORMATS['zarr']}"

    # the folder's life ------------------------------------------------------------------

    def make(self) -> None:
        """Make the folder with its parents (`make_folders`); a refusal is one line."""
        try:
            self.made = make_folders(self.path)
        except OSError as error:
            raise unwritable(self.path, error) from None

    def remove_made(self) -> None:
        """After a failed run, remove the folders `make` made when the run left nothing worth
        keeping: the study's folder whole (under its lock, or where none could be taken), its
        parents only while empty (another study's sweep may write there)."""
        if (
            not self.made
            or self.archive.exists()
            or any(self.path.glob("*.nc"))
            or any(self.parts.glob(f"*{PART_SUFFIX}"))
            or any(self.parts.glob(f"*{MARK_SUFFIX}"))
        ):
            return
        if self.path in self.made:
            shutil.rmtree(self.path)
        remove_folders([path for path in self.made if path != self.path])

    @contextlib.contextmanager
    def refusals(self) -> Iterator[None]:
        """Under the study's lock: a write the folder refuses (an `OSError` naming a path in
        it: an immutable folder under --force) becomes its one-line error, and a failed run
        removes what it made (`remove_made`) before another sweep may take the lock."""
        try:
            try:
                yield
            except OSError as error:
                if (
                    error.errno not in WRITE_REFUSALS
                    or error.filename is None
                    or not pathlib.Path(error.filename).is_relative_to(self.path)
                ):
                    raise  # not a refusal of the study folder: a bug
                raise unwritable(self.path, error) from None
        except RbstudyError:
            self.remove_made()
            raise

    def lock(self) -> AcquireReturnProxy:
        """The study's lock, taken (`rbstudy.archive.lock.study_lock`): a context manager."""
        return study_lock(self.path)

    def check_claim(self, force: bool = False) -> str | None:
        """Whether the folder may take the study's results (`folder_claim`); reads only."""
        return folder_claim(self.path.parent, self.study, force)

    def claim(self) -> None:
        """Record the study's config as the folder's (`claim_folder`)."""
        claim_folder(self.path, self.study)

    def clear_stale(self) -> None:
        """Remove the temporaries and probe files a killed sweep left (the lock is ours)."""
        for stale in [*self.parts.glob(".*.tmp"), *self.path.glob(".*.tmp"), *self.parts.glob(".probe-*")]:
            if stale.is_dir() and not stale.is_symlink():  # a zarr store's temporary
                shutil.rmtree(stale)
            else:
                stale.unlink()

    def write_config(self, text: str) -> None:
        """``study.yaml``: the resolved config ``text``, written whole."""
        write_text_atomic(text, self.path / "study.yaml")

    # the archive ------------------------------------------------------------------------

    def state(self) -> ArchiveState:
        """The `ArchiveState` of the folder's archive for its study."""
        if not self.archive.exists():
            return ArchiveState("absent")
        try:
            if self.zarr:
                batches = store_attribute(self.archive, "batches")
            else:
                with HDF5_LOCK, netCDF4.Dataset(self.archive) as nc:
                    batches = nc.getncattr("batches")
        except (OSError, AttributeError, RuntimeError, KeyError, ValueError):
            return ArchiveState(
                "damaged", (f"it cannot be read as {'a zarr store' if self.zarr else 'netCDF'}",)
            )
        if batches != batches_digest(self.study.batches):
            return ArchiveState("outdated")
        if self.zarr:
            problems = verify_store(self.archive).problems
        else:
            with HDF5_LOCK:
                problems = verify_archive(self.archive).problems
        return ArchiveState("damaged", tuple(problems)) if problems else ArchiveState("current")

    def described_by(self) -> str | None:
        """The config text the archive was written from."""
        return open_results(self.archive, ()).attrs.get("config")

    def answers_unchanged(self) -> bool:
        """Whether a rerun has nothing to write: the archive current and intact, and
        described by the study's very text."""
        return self.state().current and self.described_by() == self.study.archived_text

    def redescribe(self, started: str | None, config_text: str) -> None:
        """The same cases and code from another text (a title, a comment): the archive's
        global attributes (`provenance.global_attrs`, a run ``started`` then) and
        ``study.yaml`` (``config_text``) replaced, the data untouched."""
        if self.described_by() != self.study.archived_text:
            refresh = refresh_store_description if self.zarr else refresh_description
            refresh(self.archive, global_attrs(self.study, started=started))
            self.write_config(config_text)

    def writer(self, digests: Mapping[str, str | None], started: str | None) -> ArchiveWriter:
        """The `ArchiveWriter` of the archive from the parts, those of ``digests`` (batch id
        -> digest, None: still to come) already stored, of a run ``started`` then (its global
        attributes, `provenance.global_attrs`)."""
        parts = {batch.id: self.part_path(batch.id) for batch in self.study.batches}
        attrs = global_attrs(self.study, started=started)
        write: Callable[..., None] | None = None
        if self.regions:  # defined before any batch runs: the workers write into it
            self.generation = open_working(self.working_store, self.study, attrs)
            write = functools.partial(finish_regions, working=self.working_store)
        elif self.zarr:
            write = consolidate_store
        return ArchiveWriter(self.study, parts, digests, self.archive, attrs, write)

    # the parts --------------------------------------------------------------------------

    def make_parts(self) -> None:
        """Make ``parts/``, where the batches' parts or marks go."""
        self.parts.mkdir(exist_ok=True)

    def part(self, batch: Any) -> PartTarget | RegionTarget:
        """The `PartTarget` a task writes ``batch``'s part to, or where the workers write the
        store, its `RegionTarget` (the working store must exist: `writer`)."""
        path = str(self.part_path(batch.id))
        if not self.regions:
            return PartTarget(layout=self.layout, batch=batch, path=path)
        if self.generation is None:
            raise RuntimeError("a batch's region is written once writer() has defined the working store")
        dims = tuple(dimension.name for dimension in self.study.dimensions)
        return RegionTarget(
            self.layout,
            batch,
            path,
            str(self.working_store),
            dims,
            self.study.shape,
            self.unit_lock,
            self.generation,
        )

    def _found_generation(self):
        """The generation of the working store on disk, defined whole for this study's
        batches, else None."""
        return working_generation(self.working_store, batches_digest(self.study.batches))

    def stored(self, batches: Iterable[Any]) -> list[Any]:
        """Those of ``batches`` whose part file, or mark, is on disk (a mark counts only
        while its working store was defined for this study's batches)."""
        if self.regions and self._found_generation() is None:
            return []
        return [batch for batch in batches if self.part_path(batch.id).exists()]

    def checked(self, batches: Iterable[Any]) -> Iterator[tuple[Any, str | None]]:
        """(batch, digest) of each of ``batches``, one at a time: the digest of its intact
        part (`part_complete`) or mark (`region_complete`: of the working store on disk),
        else None."""
        generation = self._found_generation() if self.regions else None
        for batch in batches:
            path = self.part_path(batch.id)
            if self.regions:
                digest = region_complete(path, batch, self.layout, generation)
            else:
                digest = part_complete(path, batch)
            yield batch, digest

    def damaged(self, batches: Iterable[Any]) -> int:
        """How many of ``batches`` have a part with its digest beside it: a part that failed
        its check then is damaged, not unfinished (stopped between its rename and its digest);
        a mark only when it names the working store's generation (one of another store is
        not damaged, but of no use)."""
        stored = self.stored(batches)
        if self.regions and stored:
            generation = self._found_generation()
            stored = [batch for batch in stored if mark_generation(self.part_path(batch.id)) == generation]
        return sum(sealed(self.part_path(batch.id)) for batch in stored)

    @contextlib.contextmanager
    def probe(self, token: str) -> Iterator[tuple[str, str]]:
        """A file in ``parts/`` holding ``token``, for the duration: a worker that reads it
        sees the folder (`rbstudy.archive.parts.sees_folder`); yields (path, token)."""
        path = self.parts / f".probe-{token}"
        path.write_text(token)
        try:
            yield str(path), token
        finally:
            path.unlink()

    def remove_parts(self) -> int:
        """Remove the parts of the study's batches and their digests, the marks and the
        working store, left beside its current archive by a sweep killed before it removed
        them (by workers or not); how many parts or marks."""
        removed = 0
        for batch in self.study.batches:
            for path in (self.parts / f"{batch.id}{PART_SUFFIX}", self.parts / f"{batch.id}{MARK_SUFFIX}"):
                removed += path.exists()
                path.unlink(missing_ok=True)
                sidecar(path).unlink(missing_ok=True)
        self._remove_working()
        with contextlib.suppress(OSError):
            self.parts.rmdir()  # unless something else is there (job logs, another config's parts)
        return removed

    def finish_parts(self, keep: bool) -> None:
        """Once the archive holds them: ``parts/`` removed, or with ``keep`` only the parts
        of earlier versions of the config removed."""
        if not keep:
            shutil.rmtree(self.parts)
            return
        current = {self.part_path(batch.id).name for batch in self.study.batches}
        # from an earlier version of the config, or of rbstudy (whose parts were netCDF)
        for old in [*self.parts.glob(f"*{PART_SUFFIX}*"), *self.parts.glob("*.nc*")]:
            if old.name.removesuffix(SIDECAR_SUFFIX) not in current:
                old.unlink()
        self._remove_working()  # a store sealed, or left by workers before a run without

    def _remove_working(self):
        """Remove the working store and its marks: they mean nothing beside the archive."""
        if self.parts.is_dir():
            remove_marks(self.parts)
        if self.working_store.exists():
            shutil.rmtree(self.working_store)

    # the step search --------------------------------------------------------------------

    def read_search(self, working: bool = False) -> xr.Dataset | None:
        """The step search the archive holds (its group `SEARCH_GROUP`), or with ``working``
        the one under way (`SEARCH_FILE`); None where the archive has no search. Raises what
        reading a missing or damaged file raises."""
        if working:
            import xarray as xr  # here: the sweep's other commands need no xarray at import

            with HDF5_LOCK:  # the library is not thread-safe: one file at a time in a process
                return xr.load_dataset(self.search_file)
        return read_group(self.archive, SEARCH_GROUP)

    def write_search(self, dataset: xr.Dataset) -> None:
        """The probes so far to the working file, which a rerun resumes from."""
        path = self.search_file
        try:
            path.parent.mkdir(exist_ok=True)
            write_dataset_atomic(dataset, path)
        except OSError as error:
            if error.errno in WRITE_REFUSALS:  # read-only, immutable, full: the folder's fault
                raise unwritable(self.path, error) from None
            # a folder in its place, a file in its folder's
            raise RbstudyError(
                f"{path}: cannot write the step search there ({error.strerror or one_line(error)}); "
                "remove what is in its place, or sweep into another --out"
            ) from None

    def seal_search(self, dataset: xr.Dataset) -> None:
        """The finished search ``dataset`` into the archive (its group `SEARCH_GROUP`, sealed
        with it), then the working file removed, as the parts are once the archive holds
        them; an archive that holds this very search already (but for when it was run, its
        ``history``) is left as it is, byte for byte."""
        if not self._holds_search(dataset):
            put_group(self.archive, SEARCH_GROUP, dataset)
        self.drop_working_search()

    def _holds_search(self, dataset):
        try:
            kept = read_group(self.archive, SEARCH_GROUP)
        except (OSError, ValueError):
            return False
        return kept is not None and kept.assign_attrs(history=dataset.attrs["history"]).identical(dataset)

    def drop_working_search(self) -> None:
        """Remove the step search's working file, and its folder when nothing else is there."""
        with contextlib.suppress(OSError):  # what is left is read with the archive's, no harm
            self.search_file.unlink(missing_ok=True)
            self.search_file.parent.rmdir()  # unless something else is there
