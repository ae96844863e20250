"""The archive written from its parts, by a thread of its own: `ArchiveWriter`, `consolidate`.

The consolidated dataset is defined with netCDF4 and filled chunk by chunk, one part at a
time, in the batches' order as the parts arrive, its chunks compressed on every core
(`rbstudy.archive.chunks`), so memory stays bounded by the largest part whatever the size of
the study. Its checksums are computed from the values streamed through it, sealed before the
file is renamed into place. The sweep hands each part to the `ArchiveWriter` as it is
written (`ArchiveWriter.arrived`, from any thread) and waits for the archive at the end; a
run that stops (Ctrl-C, a failed batch) abandons it, and its temporary is removed.
"""

from __future__ import annotations

import functools
import itertools
import math
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent import futures
from concurrent.futures import Future, ThreadPoolExecutor
from types import TracebackType
from typing import Any, Literal, NamedTuple, Protocol

import numpy as np

from rbstudy.archive.checksums import StreamedChecksum, seal_archive
from rbstudy.archive.chunks import ChunkedArchive
from rbstudy.archive.files import temporary_beside
from rbstudy.archive.hdf5 import HDF5_LOCK, hdf5_writer, netcdf_writer
from rbstudy.archive.layout import Layout, create_variable, data_variables, fixed_coords, grid_coordinates
from rbstudy.archive.parts import part_values, read_part
from rbstudy.archive.variables import VARIABLES

__all__ = ["Arrival", "ArchiveWriter", "CopyTarget", "HELD_BYTES", "SlabWriter", "consolidate", "copy_part"]


class _Abandoned(Exception):
    """The run stopped (Ctrl-C, a failed batch): the archive will not get its parts."""


# The most bytes of computed values held for the archive beyond their part files: a part whose
# values came while more were held is read back from its file instead.
HELD_BYTES = 2**28


class Arrival(NamedTuple):
    """A batch's part as the archive's writer gets it: its ``path`` (or the mark of its
    region), its ``digest``, and its ``values`` (what the part holds, when handed over in
    memory, else None and the part is read)."""

    path: Any
    digest: str
    values: dict[str, np.ndarray] | None


class SlabWriter(Protocol):
    """What `copy_part` writes a variable through: a `ChunkedArchive.variable`, or anything
    with its ``write(index, values)``."""

    def write(self, index: tuple, values: np.ndarray) -> None:
        """``values`` into the slab at ``index`` (a slice or list of positions a dimension)."""


class CopyTarget(NamedTuple):
    """Where `copy_part` copies one variable: its ``writer``, whether it lies ``along`` each
    grid dimension, and the `StreamedChecksum` fed what is written (None: none)."""

    writer: SlabWriter
    along: tuple[bool, ...]
    stream: StreamedChecksum | None


class _Arrivals:
    """The parts of a study's batches, handed to `consolidate` in the batches' order as
    they are written (iterate: an `Arrival` per batch, waiting for each), from any
    thread.

    ``digests`` holds those of the parts already stored (None: still to compute); a store
    task reports each new one (`arrived`); `abandon` makes the waiting consolidation stop.
    A batch computed in this process may hand its values over too (`computed`, as its part
    holds them: `rbstudy.archive.parts.part_values`), so the archive takes them without
    reading the part back; at most `HELD_BYTES` are held, else values is None."""

    def __init__(self, batches, parts, digests, held_bytes=None):
        self._batches, self._parts = batches, parts
        self._digests = dict(digests)
        self._values, self._held = {}, 0
        self._held_bytes = HELD_BYTES if held_bytes is None else held_bytes
        self._taken = set()  # the batches handed to the consolidation
        self._changed = threading.Condition()
        self._abandoned = False
        self.copied = 0  # parts copied into the archive so far

    def computed(self, batch_id, values):
        size = sum(array.nbytes for array in values.values())
        with self._changed:
            if batch_id not in self._taken and self._held + size <= self._held_bytes:
                self._values[batch_id] = values
                self._held += size

    def arrived(self, batch_id, digest):
        with self._changed:
            self._digests[batch_id] = digest
            self._changed.notify_all()

    def abandon(self):
        with self._changed:
            self._abandoned = True
            self._values, self._held = {}, 0  # a failed run's traceback may keep this alive
            self._changed.notify_all()

    def consolidated(self):
        self.copied += 1

    def _ready(self, batch_id):
        return self._abandoned or self._digests.get(batch_id) is not None

    def __iter__(self) -> Iterator[Arrival]:
        for batch in self._batches:
            with self._changed:
                self._changed.wait_for(functools.partial(self._ready, batch.id))
                if self._abandoned:
                    raise _Abandoned
                digest = self._digests[batch.id]
                self._taken.add(batch.id)
                values = self._values.pop(batch.id, None)
                if values is not None:
                    self._held -= sum(array.nbytes for array in values.values())
            yield Arrival(self._parts[batch.id], digest, values)


class ArchiveWriter:
    """``target`` written from the parts of ``study.batches`` (``parts``: batch id -> path)
    as they arrive, in the batches' order, by a thread of its own from entering to `wait`'s
    true, so its compression (on one core) runs beside the batches. ``digests``:
    those of the parts already stored (None: still to come). Leaving the block on an
    exception abandons the archive (its temporary removed) before the thread is joined.
    ``write``: what writes it, `consolidate` (netCDF) or a function of its arguments
    (`rbstudy.archive.zarr_store.consolidate_store`)."""

    def __init__(
        self,
        study: Any,
        parts: Mapping[str, Any],
        digests: Mapping[str, str | None],
        target: Any,
        attrs: Mapping[str, Any],
        write: Callable[..., None] | None = None,
    ) -> None:
        self._study, self._target, self._attrs = study, target, attrs
        self._write = consolidate if write is None else write
        self._arrivals = _Arrivals(study.batches, parts, digests)
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="archive")
        self._written: Future[None] | None = None

    def __enter__(self) -> ArchiveWriter:
        arrivals = self._arrivals
        self._written = self._thread.submit(
            self._write, self._study, arrivals, self._target, self._attrs, advance=arrivals.consolidated
        )
        return self

    def arrived(self, batch_id: str, digest: str) -> None:
        """The part of ``batch_id`` is written, with ``digest`` (from any thread)."""
        self._arrivals.arrived(batch_id, digest)

    def computed(self, batch: Any, values: Mapping[str, np.ndarray]) -> None:
        """``batch``'s ``values`` (name -> array, case first), computed in this process and
        written to its part: the archive takes them from memory, not from the file (from any
        thread, before `arrived`)."""
        stored = part_values(batch, self._study.variables, values)
        # each array on its own: a view (the last sample of a series) would hold its whole
        # series in memory, uncounted by the bound
        self._arrivals.computed(
            batch.id, {name: np.require(a, requirements="O") for name, a in stored.items()}
        )

    @property
    def copied(self) -> int:
        """How many parts the archive holds so far."""
        return self._arrivals.copied

    def wait(self, timeout: float | None) -> bool:
        """Whether the archive is written, after waiting at most ``timeout`` s for it; its
        writing's error raised here."""
        written = self._written
        if written is None:
            raise RuntimeError("the archive is written inside the ArchiveWriter's with block only")
        if not futures.wait([written], timeout=timeout).done:
            return False
        written.result()
        return True

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> Literal[False]:
        if kind is not None:
            self._arrivals.abandon()  # the archive's temporary is removed before the thread ends
        self._thread.shutdown(wait=True)
        return False


def consolidate(
    study: Any,
    arriving: Iterable[Arrival],
    target: Any,
    attrs: Mapping[str, Any],
    advance: Callable[[], None] = lambda: None,
) -> None:
    """Write ``<study>.nc`` from its parts as they arrive: ``arriving`` yields the `Arrival`
    of the part of each batch of ``study.batches``, in their order, and may
    wait for a part still being computed (the archive is written while later batches run). netCDF4
    defines the archive; its chunks are then filled from the parts and compressed on every
    core (`ChunkedArchive`, through h5py). ``advance()`` after each part; then the archive
    is sealed with its checksums, hashed as the values are written, and the parts' digests."""
    shape = study.shape
    parts = zip(study.batches, arriving, strict=True)
    # the archive is defined once the first part is there, so that a disk too small for one
    # part fails on the part alone (the archive's metadata, written at once, takes its pages)
    first = next(parts, None)
    with temporary_beside(target) as temporary:
        with netcdf_writer(temporary) as nc, HDF5_LOCK:
            defined = _define_archive(nc, study, attrs)
        with hdf5_writer(temporary) as h5file:
            archive = ChunkedArchive(h5file)
            try:
                targets = {
                    name: CopyTarget(archive.variable(name, grid_rank), along, stream)
                    for name, (grid_rank, along, stream) in defined.items()
                }
                part_digests = []
                for batch, (path, digest, values) in itertools.chain([first] if first else [], parts):
                    part = read_part(path, study.variables) if values is None else values
                    copy_part(targets, part, shape)
                    part_digests.append([batch.id, digest])
                    advance()
                archive.finish(copied.writer for copied in targets.values())
            finally:
                archive.close()
        seal_archive(temporary, part_digests, {name: stream for name, (_, _, stream) in defined.items()})


class _Defined(NamedTuple):
    """An output variable as `_define_archive` defines it."""

    grid_rank: int
    along: tuple[bool, ...]
    stream: StreamedChecksum


def _define_archive(nc: Any, study: Any, attrs: Mapping[str, Any]) -> dict[str, _Defined]:
    """Create the archive's dimensions, coordinates and (empty) variables in the open ``nc``;
    name -> `_Defined` (how many of its dimensions are the grid's, whether it lies along each
    grid dimension, its `StreamedChecksum`) of the output variables."""
    grid = grid_coordinates(study)
    nc.setncatts(attrs)
    for dim in study.dimensions:
        nc.createDimension(dim.name, dim.size)
    fixed = fixed_coords(Layout.of(study))
    for name, (values, _) in fixed.items():
        nc.createDimension(name, len(values))
    for name, coordinate in grid.items():
        create_variable(nc, name, coordinate.dims, coordinate.values, coordinate.attrs)
    for name, (values, coord_attrs) in fixed.items():
        create_variable(
            nc,
            name,
            (name,),
            values.astype(object) if values.dtype.kind == "U" else values,
            coord_attrs,
        )
    targets = {}
    for name, stored in data_variables(study, grid).items():
        grid_rank = stored.grid_rank
        variable = create_variable(
            nc, name, stored.dims, attrs=stored.attrs, dtype=VARIABLES[name].dtype, grid_rank=grid_rank
        )
        targets[name] = _Defined(
            grid_rank,
            tuple(d.name in stored.dims[:grid_rank] for d in study.dimensions),
            StreamedChecksum(variable, grid_rank),
        )
    return targets


def _block(cases: np.ndarray, shape: tuple[int, ...]) -> tuple[tuple, tuple[int, ...]] | None:
    """Orthogonal indices (one per dimension) when ``cases`` (flat, C order) fill the outer
    product of their coordinates in order, else None. Batches usually do (a fixed scheme
    and dt, every value of the other axes), and one slab write replaces a write per case."""
    where = np.unravel_index(cases, shape)
    axes = [np.unique(w) for w in where]
    if math.prod(len(a) for a in axes) != len(cases):
        return None
    grid = np.ravel_multi_index(np.meshgrid(*axes, indexing="ij"), shape).ravel()
    if not np.array_equal(grid, cases):
        return None
    return tuple(slice(a[0], a[-1] + 1) if len(a) == a[-1] - a[0] + 1 else a.tolist() for a in axes), tuple(
        len(a) for a in axes
    )


def copy_part(
    targets: Mapping[str, CopyTarget], part: Mapping[str, np.ndarray], shape: tuple[int, ...]
) -> None:
    """Copy one part's cases (`read_part`) into the consolidated variables ``targets``: name
    -> its `CopyTarget`. A part holds a value per case; a variable of the scene alone takes
    its cases' values at the first position of the dimensions it does not lie along (the same
    at every other)."""
    cases = part["case"]
    if not shape:  # a one-case study
        for name, copied in targets.items():
            copied.writer.write((), part[name][0])
        return
    orthogonal = _block(cases, shape)
    # else slabs of consecutive cases: a batch cut from a long grid (one scheme and dt, 510 of
    # 100 x 1,000 spins and tilts) starts and ends inside a row; written case by case, such
    # parts took most of a large study's consolidation
    slabs = (
        [orthogonal]
        if orthogonal is not None
        else [
            (index, tuple(piece.stop - piece.start for piece in index))
            for run in np.split(cases, np.flatnonzero(np.diff(cases) != 1) + 1)
            for index in _slabs(int(run[0]), int(run[-1]) + 1, shape)
        ]
    )
    for name, (writer, along, stream) in targets.items():
        values, start = part[name], 0
        for index, sizes in slabs:
            count = math.prod(sizes)
            block = values[start : start + count].reshape(sizes + values.shape[1:])
            kept = tuple(where for where, keep in zip(index, along, strict=True) if keep)
            written = block[tuple(slice(None) if keep else 0 for keep in along)]
            writer.write(kept, written)
            if stream is not None:
                stream.wrote(kept, written)
            start += count


def _slabs(first: int, stop: int, shape: tuple[int, ...]) -> list[tuple[slice, ...]]:
    """The cases ``first`` to ``stop`` - 1 (flat, C order) of a grid of ``shape`` as at most
    2 len(shape) - 1 slabs, in order, each a tuple of slices (one per dimension)."""
    if first == stop:
        return []
    if len(shape) == 1:
        return [(slice(first, stop),)]
    inner = math.prod(shape[1:])
    (row, offset), (last_row, last_offset) = divmod(first, inner), divmod(stop, inner)
    whole_rows = tuple(slice(0, size) for size in shape[1:])
    if row == last_row:
        return [(slice(row, row + 1), *index) for index in _slabs(offset, last_offset, shape[1:])]
    slabs = []
    if offset:  # the end of a first row
        slabs += [(slice(row, row + 1), *index) for index in _slabs(offset, inner, shape[1:])]
        row += 1
    if last_row > row:
        slabs.append((slice(row, last_row), *whole_rows))
    if last_offset:  # the start of a last row
        slabs += [(slice(last_row, last_row + 1), *index) for index in _slabs(0, last_offset, shape[1:])]
    return slabs
