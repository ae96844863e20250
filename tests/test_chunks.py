"""The archive's chunks compressed on every core and written whole (`archive.chunks`): a
file so written reads, through netCDF4 and xarray, exactly as one HDF5 filled itself, in
whatever order and slabs the values come, with chunks spilled to disk and read back."""

import zlib

import h5py
import netCDF4
import numpy as np
import pytest
import xarray as xr

from rbstudy.archive import chunks
from rbstudy.archive.chunks import ChunkedArchive, shuffled, unshuffled
from rbstudy.archive.layout import COMPRESSION

GRID = (7, 23)  # two swept dimensions: chunks of (2, 5) leave edge chunks on both
OWN = (3, 4)


def _define(path, dtype, fill, chunk=(2, 5)):
    with netCDF4.Dataset(path, "w") as nc:
        for name, size in zip("abcd", GRID + OWN, strict=True):
            nc.createDimension(name, size)
        nc.createVariable("x", dtype, tuple("abcd"), fill_value=fill, chunksizes=chunk + OWN, **COMPRESSION)
        nc.createVariable("scalar", "f8", ())


def _slabs(rng, written):
    """Random slabs of the grid in random order, covering the positions ``written`` marks
    (a slice of step 1 or a list of positions per dimension)."""
    rows, columns = np.nonzero(written)
    order = rng.permutation(len(rows))
    for start in range(0, len(order), 11):
        take = order[start : start + 11]
        for row in np.unique(rows[take]):
            mine = np.sort(columns[take][rows[take] == row])
            contiguous = np.all(np.diff(mine) == 1)
            index = slice(mine[0], mine[-1] + 1) if contiguous else mine.tolist()
            yield (slice(row, row + 1), index)


@pytest.mark.parametrize("dtype, fill", [("f8", np.nan), ("i1", None), ("i8", None)])
@pytest.mark.parametrize("open_bytes", [2**28, 2000])  # the second spills chunks and reads them back
def test_chunks_written_in_any_order_read_as_hdf5_writes_them(tmp_path, monkeypatch, dtype, fill, open_bytes):
    monkeypatch.setattr(chunks, "OPEN_BYTES", open_bytes)
    rng = np.random.default_rng(5)
    values = (
        rng.standard_normal(GRID + OWN)
        if dtype == "f8"
        else rng.integers(-100, 100, GRID + OWN).astype(dtype)  # the fill (-127...) is none of them
    )
    written = rng.random(GRID) < 0.8  # some positions never written: they read as the fill
    ours, theirs = tmp_path / "ours.nc", tmp_path / "theirs.nc"
    for path in (ours, theirs):
        _define(path, dtype, fill)
    with h5py.File(ours, "r+") as h5file:
        archive = ChunkedArchive(h5file, threads=2)
        variable = archive.variable("x", grid_rank=2)
        scalar = archive.variable("scalar", grid_rank=0)
        reads = []
        monkeypatch.setattr(chunks, "unshuffled", lambda *a: reads.append(1) or unshuffled(*a))
        for index in _slabs(rng, written):
            variable.write(index, values[np.ix_(*(np.r_[i] if isinstance(i, slice) else i for i in index))])
        scalar.write((), 2.5)
        archive.finish([variable, scalar])
        archive.close()
    with netCDF4.Dataset(theirs, "a") as nc:
        for index in _slabs(np.random.default_rng(5), written):
            nc["x"][index] = values[np.ix_(*(np.r_[i] if isinstance(i, slice) else i for i in index))]
        nc["scalar"][...] = 2.5
    assert bool(reads) == (open_bytes < 2**28)
    with netCDF4.Dataset(ours) as a, netCDF4.Dataset(theirs) as b:
        a.set_auto_mask(False), b.set_auto_mask(False)
        assert np.array_equal(a["x"][...], b["x"][...], equal_nan=True)
        assert np.array_equal(a["x"][...][written], values[written])
        assert a["x"].filters() == b["x"].filters()
        assert a["scalar"][...] == 2.5
    with xr.open_dataset(ours) as dataset:
        expected = np.where(written[..., None, None], values, np.nan) if dtype == "f8" else None
        if expected is not None:
            assert np.array_equal(dataset.x.values, expected, equal_nan=True)


def test_shuffled_is_hdf5s_shuffle_filter(tmp_path):
    """The bytes of a chunk HDF5 compressed itself, inflated, are `shuffled` of its values."""
    path = tmp_path / "a.nc"
    _define(path, "f8", None)
    values = np.random.default_rng(1).standard_normal((2, 5) + OWN)
    with netCDF4.Dataset(path, "a") as nc:
        nc["x"][2:4, 5:10] = values
    with h5py.File(path, "r") as h5file:
        mask, data = h5file["x"].id.read_direct_chunk((2, 5, 0, 0))
    assert mask == 0
    assert zlib.decompress(data) == shuffled(values)
    assert np.array_equal(unshuffled(zlib.decompress(data), "f8", values.shape), values)


def test_a_variable_with_other_filters_is_refused(tmp_path):
    path = tmp_path / "a.nc"
    with netCDF4.Dataset(path, "w") as nc:
        nc.createDimension("a", 4)
        nc.createVariable("x", "f8", ("a",), zlib=True, shuffle=False, chunksizes=(2,))
    with h5py.File(path, "r+") as h5file, pytest.raises(ValueError, match="not shuffle then deflate"):
        ChunkedArchive(h5file, threads=1).variable("x", grid_rank=1)
