"""The archive's netCDF layout.

The archive's dimensions are the swept ones (named after their axes; ``dt`` ascending) then
``time``, ``node``, ``axis`` (x, y, z) and ``component`` (x, y, z, w); a variable of the
scene alone lies along the swept dimensions that change the scene only (`archive_dims`).
Coordinates are labelled by their nearest decimals (`decimal_grid`). Data variables are
compressed (`COMPRESSION`) in chunks of whole cases (`case_chunks`, about `CHUNK_BYTES`);
every attribute comes from `rbstudy.archive.variables`. A step search is stored as the
group `SEARCH_GROUP`.
"""

from __future__ import annotations

import decimal
import math
from collections.abc import Container, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from rbstudy.archive.coordinates import COORDINATES, SCHEME_COORDINATES, cf_attrs
from rbstudy.archive.ids import study_identity
from rbstudy.archive.variables import VARIABLES, variable_attrs
from rbstudy.physics.time_grid import output_times

__all__ = [
    "CHUNK_BYTES",
    "COMPRESSION",
    "FORMATS",
    "ArchiveVariable",
    "CommonStep",
    "Coordinate",
    "Layout",
    "SEARCH_GROUP",
    "archive_dims",
    "case_chunks",
    "create_variable",
    "data_variables",
    "decimal_grid",
    "fixed_coords",
    "grid_coordinates",
    "is_part",
]


# The archive's formats (``output.format``, ``sweep --format``) and the suffix of each: the
# netCDF file, or the zarr store of a cluster-scale study (`rbstudy.archive.zarr_store`).
FORMATS = {"netcdf": ".nc", "zarr": ".zarr"}


_LABELS = {"axis": ["x", "y", "z"], "component": ["x", "y", "z", "w"]}


# Compression of the consolidated archive's data variables: zlib (readable by every netCDF-4
# reader) after byte shuffling, which groups the slowly varying high bytes of neighbouring
# floats; level 4 gives nearly all of level 9's size at a fraction of its time.
COMPRESSION: dict[str, Any] = {"zlib": True, "shuffle": True, "complevel": 4}


# Target size of an archive chunk (uncompressed): `case_chunks`.
CHUNK_BYTES = 2**18


# Where `sweep --find-step` keeps its probes (`rbstudy.pipeline.step_search`): the archive's
# netCDF group, sealed with it (`put_group`), once the search is done; until then the working
# file of the study folder, which an interrupted search resumes from.
SEARCH_GROUP = "search"


class CommonStep(NamedTuple):
    """A scheme's study-wide answer of a step search, as the group keeps it: its least found
    step ``dt`` (s), met at every value of the other axes, the mean calibrated kernel
    ``seconds`` a case takes at it, and their relative ``uncertainty``. The search writes it
    (`rbstudy.pipeline.step_search`), the findings read it (`rbstudy.analysis.searched`)."""

    dt: float
    seconds: float
    uncertainty: float


# An output interval with more decimals than this is no short decimal (0.1 / 3): its grid
# keeps the plain products.
_MAX_DECIMALS = 15


@dataclass(frozen=True)
class Layout:
    """What a part file, and the archive's fixed coordinates, need to know of a study (small:
    it travels with every task)."""

    study: str
    variables: tuple
    n_times: int
    output_interval: float
    node_names: tuple
    identity: tuple  # `study_identity`

    @classmethod
    def of(cls, study: Any) -> Layout:
        """The layout of a study (a `rbstudy.pipeline.config.StudyConfig`, which this layer
        does not import)."""
        return cls(
            study=study.name,
            variables=study.variables,
            n_times=study.n_times,
            output_interval=study.output_interval,
            node_names=study.node_names,
            identity=study_identity(study),
        )


def decimal_grid(n_times: int, interval: float) -> np.ndarray:
    """The output times (`rbstudy.physics.simulate.output_times`) as the archive labels them:
    each the double nearest its decimal value, ``0.35``, not ``35 * 0.01 =
    0.35000000000000003``, so that ``ds.sel(time=0.35)`` finds it. An interval with more
    than 15 decimals is left as the plain products."""
    times = output_times(n_times, interval)
    places = -int(decimal.Decimal(repr(float(interval))).as_tuple().exponent)  # finite: an int
    if places > _MAX_DECIMALS or times[-1] * 10.0**places >= 2.0**52:
        return times
    return np.round(times, places)  # exact: k * interval * 10^places is a whole number


def fixed_coords(layout: Layout) -> dict[str, tuple[np.ndarray, dict[str, Any]]]:
    """time, axis, component and node coordinates as (values, attrs)."""
    coords: dict[str, tuple[np.ndarray, dict[str, Any]]] = {
        "time": (decimal_grid(layout.n_times, layout.output_interval), {})
    }
    coords.update({name: (np.array(labels), {}) for name, labels in _LABELS.items()})
    if layout.node_names:
        coords["node"] = (np.array(layout.node_names), {})
    for name, (_, attrs) in coords.items():
        attrs.update(cf_attrs(*COORDINATES[name]))
    return coords


def _coordinate_values(axis):
    """An axis's values as its coordinate: names as text, flags as the text ``true`` and
    ``false`` (netCDF has no booleans, and 0 and 1 would read as numbers), else floats."""
    if all(isinstance(v, bool) for v in axis.values):
        return np.array([str(v).lower() for v in axis.values], dtype=object)
    if all(isinstance(v, str) for v in axis.values):
        return np.array(axis.values, dtype=object)
    return np.array([float(v) for v in axis.values])


def grid_coordinates(study: Any) -> dict[str, Coordinate]:
    """The coordinates of the swept dimensions: name -> its `Coordinate`.

    A product dimension's coordinate is its axis; a zipped dimension gets an index coordinate
    and one auxiliary coordinate per axis. ``scheme`` and ``dt``, when not swept, are scalar
    coordinates, so that every dataset names both. Each scheme's nominal order and claimed
    invariants (`SCHEME_COORDINATES`) are auxiliary coordinates along ``scheme``.
    """
    coords: dict[str, Coordinate] = {}
    swept = {axis.target for dim in study.dimensions for axis in dim.axes}
    for name in ("scheme", "dt"):
        if name not in swept:  # then every run has the first run's
            value = getattr(study.cases.runs[0], name)
            coords[name] = Coordinate(
                (),
                np.array(value, dtype=object if name == "scheme" else float),
                cf_attrs(*COORDINATES[name]),
            )
    coords.update(_scheme_claims(study, () if "scheme" not in swept else ("scheme",)))
    for dim in study.dimensions:
        if len(dim.axes) > 1:
            coords[dim.name] = Coordinate(
                (dim.name,),
                np.arange(dim.size),
                {"long_name": "index along the zipped axes " + ", ".join(a.coordinate for a in dim.axes)},
            )
        for axis in dim.axes:
            attrs = cf_attrs(axis.units, axis.long_name)
            attrs["sweep_path"] = axis.target
            coords[axis.coordinate] = Coordinate((dim.name,), _coordinate_values(axis), attrs)
    return coords


def _scheme_claims(study, dims):
    """`SCHEME_COORDINATES` of the study's schemes, along ``dims`` (the scheme dimension, or
    none for a one-scheme study); invariants as space-separated names, "none" for none."""
    schemes = (
        list(next(a.values for d in study.dimensions for a in d.axes if a.target == "scheme"))
        if dims
        else [study.cases.runs[0].scheme]
    )
    swept_order = study.order_dimension
    coords: dict[str, Coordinate] = {}
    for name, (_, units, long_name) in SCHEME_COORDINATES.items():
        values = [study.schemes[scheme][name] for scheme in schemes]
        along = dims
        if name == "claimed_invariants":
            values = np.array([" ".join(v) or "none" for v in values], dtype=object)
        elif name == "scheme_origin":
            values = np.array(values, dtype=object)
        if name == "nominal_order" and swept_order is not None:
            along = dims + (swept_order.dimension,)  # the orders of a swept composition
        shape = (len(values),) * bool(dims) + np.shape(values)[1:]
        coords[name] = Coordinate(along, np.asarray(values).reshape(shape), cf_attrs(units, long_name))
    return coords


def case_chunks(grid_shape: tuple[int, ...], own_shape: tuple[int, ...], itemsize: int) -> tuple[int, ...]:
    """Chunk shape of an archive variable: whole along its own dimensions (time, node,
    axis, ...), and along the grid's dimensions, from the last, as many cases as keep a
    chunk near `CHUNK_BYTES`. The archive is written part by part, and a part holds whole
    cases: chunks of whole cases are filled by one part, each compressed once. netCDF's
    default chunks cut across cases, so that every part decompressed and compressed again
    the chunks it shared with the others, which took most of the consolidation's time."""
    chunk = [max(1, size) for size in own_shape]  # netCDF refuses a chunk of length 0
    room = max(1, CHUNK_BYTES // max(1, itemsize * math.prod(own_shape)))
    grid_chunk: list[int] = []
    for size in reversed(grid_shape):
        take = max(1, min(size, room))
        grid_chunk.insert(0, take)
        room //= take
    return tuple(grid_chunk + chunk)


def create_variable(
    nc: Any,
    name: str,
    dims: tuple[str, ...],
    values: np.ndarray | None = None,
    attrs: Mapping[str, Any] | None = None,
    dtype: Any = None,
    grid_rank: int = 0,
) -> Any:
    """A netCDF variable; coordinates get ``values``, data variables a NaN fill (floats) and
    compression (zlib with byte shuffling: `COMPRESSION`) in chunks of whole cases
    (`case_chunks`) along their first ``grid_rank`` dimensions."""
    if values is not None:
        dtype = str if values.dtype == object else values.dtype
    fill = np.nan if values is None and np.dtype(dtype).kind == "f" else None
    compression = COMPRESSION if values is None and dims else {}
    if compression:
        shape = tuple(len(nc.dimensions[d]) for d in dims)
        compression = {
            **compression,
            "chunksizes": case_chunks(shape[:grid_rank], shape[grid_rank:], np.dtype(dtype).itemsize),
        }
    variable = nc.createVariable(name, dtype, dims, fill_value=fill, **compression)
    if attrs:
        variable.setncatts(
            {k: (np.array(v, dtype=np.int8) if k == "flag_values" else v) for k, v in attrs.items()}
        )
    if values is not None:
        variable[...] = values
    return variable


class Coordinate(NamedTuple):
    """A coordinate of the swept dimensions (`grid_coordinates`): its dimensions, its values
    and its attributes, in the order xarray takes a variable as a tuple."""

    dims: tuple[str, ...]
    values: np.ndarray
    attrs: dict[str, Any]


class ArchiveVariable(NamedTuple):
    """How an output variable lies in the archive, whatever format stores it: its dimensions
    (`archive_dims`), its attributes, and how many of its dimensions are the grid's."""

    dims: tuple[str, ...]
    attrs: dict[str, Any]
    grid_rank: int


def data_variables(study: Any, grid: Mapping[str, Coordinate]) -> dict[str, ArchiveVariable]:
    """The archive's output variables: name -> its `ArchiveVariable`, the attributes from
    `rbstudy.archive.variables` with the auxiliary coordinates of ``grid``
    (`grid_coordinates`) that CF readers attach to it."""
    found = {}
    for name in study.variables:
        along = archive_dims(study, name)
        attrs = variable_attrs(name)
        # the auxiliary coordinates (zipped axes, unswept scheme and dt, the schemes'
        # claims): those along its dimensions
        auxiliary = [
            coordinate
            for coordinate, held in grid.items()
            if held.dims != (coordinate,) and set(held.dims) <= set(along)
        ]
        if auxiliary:
            attrs["coordinates"] = " ".join(auxiliary)
        found[name] = ArchiveVariable(
            dims=along, attrs=attrs, grid_rank=len(along) - len(VARIABLES[name].dims)
        )
    return found


def archive_dims(study: Any, name: str) -> tuple[str, ...]:
    """The dimensions of variable ``name`` in ``study``'s archive: the swept ones (a
    variable of the scene alone: those along which the scene changes), then its own."""
    grid = study.scene_dims if VARIABLES[name].per_scene else tuple(d.name for d in study.dimensions)
    return grid + VARIABLES[name].dims


def is_part(attributes: Container[str], dimensions: Container[str]) -> bool:
    """Whether a netCDF file with these global ``attributes`` and ``dimensions`` (names) is
    one batch's part file rather than a study's archive."""
    return "batch" in attributes and "case" in dimensions
