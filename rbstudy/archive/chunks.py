"""The archive's chunks compressed on every core and written whole (HDF5's direct chunk write).

HDF5 runs a chunk through its filters (here byte shuffling, then zlib) inside the write, one
chunk at a time under its one lock: a million-case archive (1.5 GB) spent most of its writing
compressing on one core, which no number of cores shortened. Here each chunk of an archive variable is
filled in memory from the parts as they arrive; once its last value has come, it is shuffled
and compressed by a pool of threads (zlib lets the GIL go) and written as it is with h5py's
direct chunk write. The bytes are those HDF5's own filters would produce, so any netCDF-4
reader reads the file as before.

A chunk whose values arrive out of order stays in memory until it is whole; past
`OPEN_BYTES` of such chunks the oldest is written as it stands (its missing values the fill
value) and read back when the rest arrives, as HDF5's chunk cache does.
"""

from __future__ import annotations

import collections
import concurrent.futures
import itertools
import os
import zlib
from collections.abc import Iterable
from typing import Any

import h5py
import numpy as np

__all__ = ["ChunkedArchive"]

# Uncompressed bytes of partly filled chunks kept in memory: parts in C order of the grid
# leave at most a chunk or two of each variable open; a study whose batches interleave (a
# scheme along the last dimension) would otherwise hold the whole archive.
OPEN_BYTES = 2**28
# Chunks handed to the compressing threads and not yet written, per thread: enough to keep
# them busy while the archive's thread reads the next part, few enough to bound memory
# (chunks are ~256 KiB: `layout.CHUNK_BYTES`).
IN_FLIGHT_PER_THREAD = 16
# The filters every archive variable is created with (`layout.COMPRESSION`), in HDF5's order.
_FILTERS = (h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE)


def shuffled(values: np.ndarray) -> bytes:
    """The bytes of ``values`` (C order) as HDF5's shuffle filter lays them out: the first
    byte of every element, then the second, and so on (a no-op for one-byte elements)."""
    flat = np.ascontiguousarray(values).reshape(-1)
    return np.ascontiguousarray(flat.view(np.uint8).reshape(flat.size, flat.itemsize).T).tobytes()


def unshuffled(data: bytes, dtype: Any, shape: tuple[int, ...]) -> np.ndarray:
    """The array of ``dtype`` and ``shape`` whose `shuffled` bytes are ``data``."""
    dtype = np.dtype(dtype)
    planes = np.frombuffer(data, dtype=np.uint8).reshape(dtype.itemsize, -1)
    return planes.T.copy().view(dtype).reshape(shape)  # a copy: frombuffer's is read-only


def _compressed(values, level):
    return zlib.compress(shuffled(values), level)


def _pieces(index, size, step):
    """The chunks that positions ``index`` (a slice of step 1, or a list) of a dimension of
    ``size`` touch, with chunks of ``step`` positions: (chunk number, where in the written
    block, where in the chunk) each, slices for a slice, arrays for a list."""
    if isinstance(index, slice):
        start, stop, stride = index.indices(size)
        if stride != 1:
            raise ValueError(f"slices of step 1 only, not {index}")
        for chunk in range(start // step, (stop - 1) // step + 1) if stop > start else ():
            first, last = max(start, chunk * step), min(stop, (chunk + 1) * step)
            yield chunk, slice(first - start, last - start), slice(first - chunk * step, last - chunk * step)
        return
    positions = np.asarray(index, dtype=np.int64)
    chunks = positions // step
    for chunk in np.unique(chunks):
        where = np.flatnonzero(chunks == chunk)
        yield int(chunk), where, positions[where] - chunk * step


def _at(pieces):
    """An index from one piece per dimension: slices as they are; with any array, an outer
    product (`numpy.ix_`) of them all."""
    if all(isinstance(piece, slice) for piece in pieces):
        return tuple(pieces)
    return np.ix_(
        *(np.arange(piece.start, piece.stop) if isinstance(piece, slice) else piece for piece in pieces)
    )


class _ChunkedVariable:
    """One archive variable written chunk by chunk: ``write(index, values)`` over its first
    ``grid_rank`` dimensions (its own, after them, are whole in every chunk)."""

    def __init__(self, archive, dataset, grid_rank):
        self.archive = archive
        self.dataset = dataset
        self.grid_rank = grid_rank
        # read once: each of h5py's properties is a call into HDF5 under h5py's lock
        self.shape, self.dtype, self.fill = dataset.shape, dataset.dtype, dataset.fillvalue
        self.chunk = dataset.chunks
        self.level = _deflate_level(dataset)
        self.open = {}  # chunk number (grid dimensions) -> [values, which grid positions came]
        self.on_disk = {}  # chunk number -> the positions it holds, of a chunk written partly

    def write(self, index, values):
        """Write ``values`` (the block at ``index``: a slice of step 1 or a list of positions
        per grid dimension, then every position of the variable's own dimensions)."""
        if 0 in self.shape:
            return
        values = np.asarray(values)
        pieces = [
            list(_pieces(where, size, step))
            for where, size, step in zip(index, self.shape, self.chunk, strict=False)
        ]
        for combination in itertools.product(*pieces):
            number = tuple(chunk for chunk, _, _ in combination)
            buffer, came = self._chunk(number)
            into = _at([inside for _, _, inside in combination])
            buffer[into] = values[_at([block for _, block, _ in combination])]
            came[into] = True
            if came.all():
                self._flush(number)

    def _chunk(self, number):
        if number in self.open:
            return self.open[number]
        shape = self.chunk
        if number in self.on_disk:  # written partly: read back, and go on filling it
            came = self.on_disk.pop(number)
            self.archive.write_all()  # its first values may still be on their way
            _, data = self.dataset.id.read_direct_chunk(self._offset(number))
            values = unshuffled(zlib.decompress(data), self.dtype, shape)
        else:
            values = np.full(shape, self.fill, dtype=self.dtype)
            # the positions of an edge chunk beyond the variable come never: count them in
            inside = tuple(
                slice(0, min(step, size - chunk * step))
                for chunk, step, size in zip(number, shape, self.shape, strict=False)
            )
            came = np.ones(shape[: self.grid_rank], dtype=bool)
            came[inside] = False
        self.open[number] = [values, came]
        self.archive.opened(self, number, values.nbytes)
        return self.open[number]

    def _offset(self, number):
        return tuple(chunk * step for chunk, step in zip(number, self.chunk, strict=False)) + (0,) * (
            len(self.chunk) - self.grid_rank
        )

    def _flush(self, number):
        """Hand chunk ``number`` to the compressing threads; remembered as partly written when
        some of its values have not come."""
        values, came = self.open.pop(number)
        if not came.all():
            self.on_disk[number] = came
        self.archive.compress(self.dataset, self._offset(number), values, self.level)
        self.archive.closed(self, number)

    def flush_all(self):
        for number in list(self.open):
            self._flush(number)


class _WholeVariable:
    """A variable without dimensions (a one-case study's scalars), written as it is."""

    def __init__(self, dataset):
        self.dataset = dataset

    def write(self, index, values):
        self.dataset[...] = values

    def flush_all(self):
        pass


def _deflate_level(dataset):
    """The zlib level of ``dataset``, after checking that its filters are `_FILTERS`."""
    plist = dataset.id.get_create_plist()
    filters = [plist.get_filter(k) for k in range(plist.get_nfilters())]
    if tuple(code for code, *_ in filters) != _FILTERS:
        raise ValueError(f"{dataset.name}: filters {filters}, not shuffle then deflate")
    return filters[1][2][0]


class ChunkedArchive:
    """The data variables of an open h5py file written chunk by chunk, compressed on
    ``threads`` threads. ``variable(name, grid_rank)`` gives a writer with ``write(index,
    values)``; ``finish()`` writes what is left (a chunk never written reads as the fill
    value, as HDF5 leaves it)."""

    def __init__(self, h5file: h5py.File, threads: int | None = None) -> None:
        self.file = h5file
        threads = threads or len(os.sched_getaffinity(0))
        self.pool = concurrent.futures.ThreadPoolExecutor(threads, thread_name_prefix="compress")
        self.in_flight: collections.deque[tuple[Any, tuple[int, ...], concurrent.futures.Future[bytes]]] = (
            collections.deque()
        )
        self.max_in_flight = IN_FLIGHT_PER_THREAD * threads
        self.open_chunks: collections.OrderedDict[tuple[_ChunkedVariable, tuple[int, ...]], int] = (
            collections.OrderedDict()
        )  # (variable, number) -> bytes, oldest first
        self.open_bytes = 0

    def variable(self, name: str, grid_rank: int) -> _WholeVariable | _ChunkedVariable:
        """The writer of variable ``name``, chunked along its first ``grid_rank`` dimensions."""
        dataset = self.file[name]
        if dataset.chunks is None:  # a variable without dimensions: stored whole, uncompressed
            return _WholeVariable(dataset)
        return _ChunkedVariable(self, dataset, grid_rank)

    def opened(self, variable: _ChunkedVariable, number: tuple[int, ...], size: int) -> None:
        """Chunk ``number`` of ``variable`` holds ``size`` bytes in memory: past `OPEN_BYTES`
        the oldest other chunk is written as it stands."""
        self.open_chunks[(variable, number)] = size
        self.open_bytes += size
        while self.open_bytes > OPEN_BYTES and len(self.open_chunks) > 1:
            oldest, _ = next(iter(self.open_chunks.items()))
            if oldest == (variable, number):  # not the one being filled
                self.open_chunks.move_to_end(oldest)
                continue
            oldest[0]._flush(oldest[1])

    def closed(self, variable: _ChunkedVariable, number: tuple[int, ...]) -> None:
        """Chunk ``number`` of ``variable`` is written: no longer held."""
        self.open_bytes -= self.open_chunks.pop((variable, number))

    def compress(self, dataset: Any, offset: tuple[int, ...], values: np.ndarray, level: int) -> None:
        """Compress ``values``, the chunk at ``offset`` of ``dataset``, on a thread, and write
        the oldest compressed chunks while too many are in flight."""
        self.in_flight.append((dataset, offset, self.pool.submit(_compressed, values, level)))
        while len(self.in_flight) > self.max_in_flight:
            self._write_oldest()

    def _write_oldest(self):
        dataset, offset, compressed = self.in_flight.popleft()
        dataset.id.write_direct_chunk(offset, compressed.result())

    def write_all(self) -> None:
        """Write every compressed chunk in flight."""
        while self.in_flight:
            self._write_oldest()

    def finish(self, variables: Iterable[Any]) -> None:
        """Write every chunk of ``variables`` still open, then wait for every write."""
        for variable in variables:
            variable.flush_all()
        self.write_all()

    def close(self) -> None:
        """Stop the threads (what they still hold is dropped: the archive failed)."""
        self.pool.shutdown(wait=True, cancel_futures=True)
