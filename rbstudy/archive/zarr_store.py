"""The archive as a zarr v3 store, ``<study>/<study>.zarr``: the second format (issue 42).

The same dataset as the netCDF archive (`rbstudy.archive.writer`): the dimensions,
coordinates and attributes of `rbstudy.archive.layout` and `rbstudy.archive.variables`, the
global attributes of `rbstudy.archive.provenance`, the values copied from the same parts in
the batches' order, each part's cases into their region (`rbstudy.archive.writer.copy_part`),
so memory stays bounded by the largest part. It is laid out as xarray's zarr backend reads
it (``dimension_names``, the ``_FillValue`` attribute of a variable that has one, the
``coordinates`` attribute), so ``xarray.open_zarr`` gives the dataset ``open_dataset`` gives
of the netCDF archive, apart from encoding. Chunks are the netCDF archive's
(`layout.case_chunks`); where a variable has several, they are gathered into shards of
about `SHARD_BYTES` (zarr v3 sharding: one file per shard, not per chunk). The store is
written in a temporary folder beside its place, sealed with its checksums
(`rbstudy.archive.zarr_integrity`) and renamed into place: a reader never sees half a store.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import json
import math
import os
import pathlib
import shutil
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np

from rbstudy.archive.chunks import OPEN_BYTES
from rbstudy.archive.files import temporary_folder_beside, write_text_atomic
from rbstudy.archive.layout import (
    FORMATS,
    Coordinate,
    Layout,
    case_chunks,
    data_variables,
    fixed_coords,
    grid_coordinates,
)
from rbstudy.archive.parts import read_part
from rbstudy.archive.variables import VARIABLES
from rbstudy.archive.writer import Arrival, CopyTarget, copy_part
from rbstudy.archive.zarr_integrity import GROUP, seal_store

__all__ = [
    "SHARD_BYTES",
    "SUFFIX",
    "UnitPiece",
    "consolidate_store",
    "define_store",
    "dimensions_of",
    "finish_store",
    "is_store",
    "open_header",
    "refresh_store_description",
    "store_attribute",
    "store_attributes",
    "unit_bounds",
    "unit_pieces",
]


SUFFIX = FORMATS["zarr"]


# Target size of a shard (uncompressed): 128 of the archive's chunks (`CHUNK_BYTES`, 256 KiB).
# A shard is one file: a million cases' 35 variables take ~1,600 files, not ~200,000. Writing
# into part of a shard rewrites it, so it stays within a few parts' worth of a variable.
SHARD_BYTES = 2**25


# Blosc's zstd after byte shuffling: like the netCDF archive's zlib with shuffle, the slowly
# varying high bytes of neighbouring floats grouped, at a fraction of zlib's time. Level 1:
# several times level 4's speed for nearly its ratio on the --scale study's arrays, and a
# somewhat lower ratio on the default study's long series.
_COMPRESSION_LEVEL = 1


def is_store(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a zarr store (a folder with its root ``zarr.json``)."""
    path = pathlib.Path(path)
    return path.is_dir() and (path / "zarr.json").is_file()


def _compressors():
    from zarr.codecs import BloscCodec

    return (BloscCodec(cname="zstd", clevel=_COMPRESSION_LEVEL, shuffle="shuffle"),)


def _json(value):
    """An attribute value as JSON holds it (numpy arrays and numbers as lists and numbers)."""
    value = np.asarray(value) if isinstance(value, np.ndarray | np.generic) else value
    return value.tolist() if isinstance(value, np.ndarray) else value


def _shards(shape, chunks, grid_rank, itemsize, batch_cases):
    """The shard shape of a variable of ``shape`` in ``chunks`` of values of ``itemsize``
    bytes: whole chunks gathered along its grid dimensions, from the last, up to
    `SHARD_BYTES` and to the cases of a batch (``batch_cases``, the largest); None (no
    sharding) where the variable is one chunk.

    A shard is written whole: one that spans k batches is read, merged and written k times
    by the workers (`rbstudy.archive.zarr_regions`), and stays open in memory across k parts
    in the local writer (`_Units`). Shards of 32 MiB spanned the whole of a 1e6-case study's
    per-case variables (245 batches), and writing its store from parts on one machine took
    several times as long as the netCDF archive's."""
    if math.prod(math.ceil(size / chunk) for size, chunk in zip(shape, chunks, strict=True)) <= 1:
        return None
    by_bytes = SHARD_BYTES // max(1, math.prod(chunks) * itemsize)
    by_batch = batch_cases // max(1, math.prod(chunks[:grid_rank]))
    room = max(1, min(by_bytes, by_batch))
    shard = list(chunks)
    for k in reversed(range(grid_rank)):
        take = max(1, min(math.ceil(shape[k] / chunks[k]), room))
        shard[k] = take * chunks[k]
        room //= take
    return tuple(shard)


def dimensions_of(array: Any) -> tuple[str, ...]:
    """The dimension names of zarr ``array``, a tuple (zarr gives None for a scalar's: a
    variable of the scene alone where no scene axis is swept)."""
    return tuple(array.metadata.dimension_names or ())


def unit_bounds(array: Any, unit: tuple[int, ...]) -> tuple[slice, ...]:
    """The region of zarr ``array`` (a slice per grid dimension) its unit ``unit`` covers: the
    unit's index in the grid of its shards, or of its chunks where it has none."""
    shape = array.shards or array.chunks
    return tuple(
        slice(k * size, min((k + 1) * size, whole))
        for k, size, whole in zip(unit, shape, array.shape, strict=False)
    )


class UnitPiece(NamedTuple):
    """The part of a write that falls in one unit of a zarr array (`unit_pieces`): the unit's
    index (`unit_bounds`), the positions inside it as a numpy index, and the values there."""

    unit: tuple[int, ...]
    inside: Any
    block: np.ndarray


def unit_pieces(array: Any, index: tuple, values: np.ndarray) -> Iterator[UnitPiece]:
    """``values`` at ``index`` (a slice or a list of positions per grid dimension) of zarr
    ``array``, split by the units they fall in (`unit_bounds`): a `UnitPiece` per unit."""
    shape = array.shards or array.chunks
    positions = [
        np.arange(*piece.indices(size)) if isinstance(piece, slice) else np.asarray(piece)
        for piece, size in zip(index, array.shape, strict=False)
    ]
    groups = [
        [(int(key), np.flatnonzero(where // size == key)) for key in np.unique(where // size)]
        for where, size in zip(positions, shape, strict=False)
    ]
    for pieces in itertools.product(*groups):
        taken = [rows for _, rows in pieces]
        inside = [
            where[rows] - key * size
            for (key, rows), where, size in zip(pieces, positions, shape[: len(positions)], strict=True)
        ]
        block = values[np.ix_(*taken)] if taken else values
        yield UnitPiece(tuple(key for key, _ in pieces), np.ix_(*inside) if inside else ..., block)


class _Units:
    """The store's variables filled in memory a unit at a time (a shard, or a chunk where a
    variable is not sharded) and each unit written whole once all its values are there: a
    zarr write into part of a unit reads, decodes, merges and encodes it again through zarr's
    event loop (abaqus_top, 54 parts of 32 variables written as they came, took several times
    the netCDF archive's time). Parts in C order fill a unit or two of a variable at a
    time; past `OPEN_BYTES` of open units (batches that interleave) the oldest is written as
    it stands, and read back when its other values come, as `rbstudy.archive.chunks` does."""

    def __init__(self, arrays):
        self.arrays = arrays  # name -> zarr array
        self.open = {}  # (name, unit) -> its buffer, oldest first
        self.filled = collections.Counter()  # (name, unit) -> values written into it so far
        self.stored = set()  # (name, unit) written to the store once: a new buffer reads it
        self.ready = {}  # (name, unit) -> its buffer: to write at the next `flush`

    def region(self, name):
        return _Region(self, name)

    def _buffer(self, name, unit):
        if (name, unit) in self.ready:  # spilled or whole, not written yet: written to again
            self.open[(name, unit)] = self.ready.pop((name, unit))
        if (name, unit) not in self.open:
            array = self.arrays[name]
            bounds = unit_bounds(array, unit)
            if (name, unit) in self.stored:  # an array (zarr gives a scalar's value as a number)
                buffer = np.asarray(array[bounds])
            else:
                shape = tuple(piece.stop - piece.start for piece in bounds) + array.shape[len(bounds) :]
                buffer = np.full(shape, array.fill_value, dtype=array.dtype)
            self.open[(name, unit)] = buffer
        return self.open[(name, unit)]

    def write(self, name, index, values):
        """``values`` at ``index`` (a slice or a list of positions per grid dimension) of
        variable ``name``: into the buffers of the units they fall in."""
        for unit, inside, block in unit_pieces(self.arrays[name], index, values):
            buffer = self._buffer(name, unit)
            buffer[inside] = block
            self.filled[(name, unit)] += block.size
            if self.filled[(name, unit)] >= buffer.size:  # whole (or written twice: read back later)
                self.ready[(name, unit)] = self.open.pop((name, unit))
        while sum(buffer.nbytes for buffer in self.open.values()) > OPEN_BYTES and len(self.open) > 1:
            oldest = next(iter(self.open))
            self.ready[oldest] = self.open.pop(oldest)

    def flush(self, pool, everything=False):
        """Write the units that are ready (with ``everything``, the open ones too), one thread
        per variable (zarr's event loop overlaps their encoding and files)."""
        if everything:
            self.ready.update(self.open)
            self.open.clear()
        by_variable = collections.defaultdict(list)
        for (name, unit), buffer in self.ready.items():
            by_variable[name].append((unit, buffer))
            self.stored.add((name, unit))
        self.ready = {}
        for _ in pool.map(self._store, by_variable.items()):
            pass

    def _store(self, item):
        name, units = item
        for unit, buffer in units:
            self.arrays[name][unit_bounds(self.arrays[name], unit)] = buffer


class _Region:
    """One variable of the store, as `copy_part` writes it (``write(index, values)``)."""

    def __init__(self, units, name):
        self.units, self.name = units, name

    def write(self, index: tuple, values: np.ndarray) -> None:
        self.units.write(self.name, index, np.asarray(values))


# Threads writing the units of a part: one per variable, up to this many, so that zarr's
# event loop overlaps their encoding and files.
_WRITERS = 8


def define_store(folder: str | os.PathLike[str], study: Any, attrs: dict[str, Any]) -> dict[str, Any]:
    """The store's group, coordinates and (empty) output variables in ``folder``; name -> its
    zarr array, of the output variables."""
    import zarr
    from xarray.backends.zarr import FillValueCoder  # xarray's encoding of `_FillValue`

    group = zarr.create_group(store=str(folder), zarr_format=3, attributes=attrs)
    grid = grid_coordinates(study)
    coordinates = dict(grid)
    coordinates.update(
        {
            name: Coordinate((name,), values, attrs_)
            for name, (values, attrs_) in fixed_coords(Layout.of(study)).items()
        }
    )
    for name, coordinate in coordinates.items():
        values = np.asarray(coordinate.values)
        text = values.dtype.kind in "OU"
        array = group.create_array(
            name,
            shape=values.shape,
            dtype=str if text else values.dtype,
            dimension_names=coordinate.dims,
            attributes={key: _json(value) for key, value in coordinate.attrs.items()},
            compressors=None,
        )
        array[...] = values.astype(object) if text else values
    batch_cases = max((len(batch.cases) for batch in study.batches), default=1)
    arrays = {}
    sizes = {dim.name: dim.size for dim in study.dimensions} | {
        name: len(coordinate.values)
        for name, coordinate in coordinates.items()
        if len(np.shape(coordinate.values)) == 1
    }
    for name, (dims, attrs_, grid_rank) in data_variables(study, grid).items():
        dtype = np.dtype(VARIABLES[name].dtype)
        shape = tuple(sizes[dim] for dim in dims)
        chunks = tuple(
            max(1, chunk) for chunk in case_chunks(shape[:grid_rank], shape[grid_rank:], dtype.itemsize)
        )
        floating = dtype.kind == "f"
        if floating:  # as the netCDF archive's NaN fill, which xarray masks
            attrs_["_FillValue"] = FillValueCoder.encode(np.nan, dtype)
        arrays[name] = group.create_array(
            name,
            shape=shape,
            dtype=dtype,
            chunks=chunks,
            shards=_shards(shape, chunks, grid_rank, dtype.itemsize, batch_cases),
            compressors=_compressors(),
            fill_value=np.nan if floating else 0,
            dimension_names=dims,
            attributes={key: _json(value) for key, value in attrs_.items()},
        )
    return arrays


def consolidate_store(
    study: Any,
    arriving: Iterable[Arrival],
    target: str | os.PathLike[str],
    attrs: dict[str, Any],
    advance: Callable[[], None] = lambda: None,
) -> None:
    """Write ``<study>.zarr`` from its parts as they arrive: the contract of
    `rbstudy.archive.writer.consolidate` (``arriving`` yields the `Arrival` of each batch's
    part in the batches' order; ``advance()`` after each part), the store defined once the
    first part is there, each part's cases written into their region, then the store sealed
    with its checksums and the parts' digests (`seal_store`) and renamed into place."""
    parts = zip(study.batches, arriving, strict=True)
    first = next(parts, None)
    with temporary_folder_beside(target) as temporary:
        arrays = define_store(temporary, study, attrs)
        units = _Units(arrays)
        targets = {
            name: CopyTarget(
                units.region(name),
                tuple(d.name in dimensions_of(array) for d in study.dimensions),
                None,
            )
            for name, array in arrays.items()
        }
        part_digests = []
        with ThreadPoolExecutor(_WRITERS, thread_name_prefix="zarr") as pool:
            for batch, (path, digest, values) in itertools.chain([first] if first else [], parts):
                part = read_part(path, study.variables) if values is None else values
                copy_part(targets, part, study.shape)
                units.flush(pool)
                part_digests.append([batch.id, digest])
                advance()
            units.flush(pool, everything=True)
        finish_store(temporary, part_digests)


def finish_store(path: str | os.PathLike[str], part_digests: list[list[str]]) -> None:
    """The store at ``path`` made whole: the files of writes killed inside zarr and an earlier
    seal removed, every array's metadata copied into the root's ``zarr.json`` (consolidated:
    xarray.open_zarr reads it in one file, and without a warning, as a cluster's file system
    prefers; each array's own ``zarr.json`` stays, which other readers read, rbstudy too), then
    sealed with its checksums and ``part_digests`` (`seal_store`)."""
    import zarr

    # what a write killed inside zarr left (it writes a file as <key>.<id>.partial, renamed)
    for partial in pathlib.Path(path).rglob("*.partial"):
        partial.unlink()
    # the seal of a sweep killed before it renamed the store: sealed again, whole
    shutil.rmtree(pathlib.Path(path) / GROUP, ignore_errors=True)
    # zarr warns that the v3 spec does not define consolidated metadata yet
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Consolidated metadata", UserWarning)
        zarr.consolidate_metadata(str(path), zarr_format=3)
    seal_store(path, part_digests)


def _open_group(path, mode="r"):
    import zarr

    return zarr.open_group(str(path), mode=mode, zarr_format=3, use_consolidated=False)


def store_attributes(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The global attributes of the store at ``path``, read from its root ``zarr.json`` alone
    (opening the group through zarr reads more, and a worker reads them under each unit's
    lock); raises `OSError`, `ValueError` or `KeyError` where the store cannot be read."""
    return json.loads((pathlib.Path(path) / "zarr.json").read_text())["attributes"]


def store_attribute(path: str | os.PathLike[str], name: str) -> Any:
    """The global attribute ``name`` of the store at ``path``; raises `KeyError` without it,
    `OSError` or `ValueError` where the store cannot be read."""
    return store_attributes(path)[name]


def refresh_store_description(path: str | os.PathLike[str], attrs: Mapping[str, Any]) -> None:
    """Replace the global attributes of the store at ``path`` (its title, config text and
    provenance) without touching its data, as `rbstudy.archive.rewrite.refresh_description`
    does for the netCDF archive: the root's ``zarr.json`` is written anew whole, through a
    temporary file and a rename, its consolidated metadata kept (zarr's own update of the
    attributes drops it), holding ``attrs`` alone; no checksum covers what changes."""
    root = pathlib.Path(path) / "zarr.json"
    metadata = json.loads(root.read_text())
    metadata["attributes"] = {key: _json(value) for key, value in attrs.items()}
    write_text_atomic(json.dumps(metadata, indent=2), root)


class _Variable:
    """A zarr array as `rbstudy.archive.reader` reads a netCDF4 variable: ``dimensions``,
    ``dtype`` (``str`` for text), ``size``, its values by ``[...]``."""

    def __init__(self, array):
        self._array = array
        self.dimensions = dimensions_of(array)
        self.dtype = str if array.dtype.kind in "OUT" else array.dtype
        self.size = array.size

    def __getitem__(self, index):
        return self._array[index]


class _Header:
    """A zarr store's root group as `rbstudy.archive.reader` reads an open netCDF4 dataset:
    its global attributes, variables and dimensions (name -> a ``range`` of its length)."""

    def __init__(self, group):
        self._attrs = dict(group.attrs)
        self.variables = {name: _Variable(array) for name, array in group.arrays()}
        self.dimensions = {}
        for variable in self.variables.values():
            for dim, size in zip(variable.dimensions, variable._array.shape, strict=True):
                self.dimensions.setdefault(dim, range(size))
        self.groups = [name for name, _ in group.groups() if name != GROUP]

    def ncattrs(self):
        return list(self._attrs)

    def getncattr(self, name):
        return self._attrs[name]

    def set_auto_maskandscale(self, flag):
        """Values are read as stored: zarr applies no mask or scale."""

    def __getitem__(self, name):
        return self.variables[name]


@contextlib.contextmanager
def open_header(path: str | os.PathLike[str]) -> Iterator[_Header]:
    """The store at ``path`` opened for `rbstudy.archive.reader`'s checks (`_Header`)."""
    yield _Header(_open_group(path))
