"""Results on disk: part files per batch and the consolidated CF-1.11 dataset of a study.

Layout (docs/architecture.md): ``<root>/<study>/study.yaml`` (the resolved config),
``parts/<batch-id>.nc`` (one finished batch, dimension ``case``), ``<study>.nc`` (every
case on the study's grid) and `OWNER` (the config whose study the folder holds, which the
archive and every part name too: `IDENTITY`). Every
file is written under a temporary name in the same folder and renamed (the file and then its
folder synced to disk first), so a reader, or a rerun after a kill or a machine crash, never
sees half a file; every part and the archive carry checksums
(`rbstudy.pipeline.integrity`), so that a file damaged later is never reused.

The consolidated dataset is defined with netCDF4 and filled chunk by chunk, one part at a
time, its chunks compressed on every core (`rbstudy.pipeline.chunks`), so memory stays
bounded by the largest part whatever the size of the study. Its dimensions are
the swept ones (named after their axes; ``dt`` ascending) then ``time``, ``node``, ``axis``
(x, y, z) and ``component`` (x, y, z, w); a variable of the scene alone lies along the swept
dimensions that change the scene only (`archive_dims`). Every attribute comes from
`rbstudy.pipeline.variables`.
"""

import datetime
import decimal
import errno
import hashlib
import itertools
import math
import os
import pathlib
import platform
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from importlib import metadata
from typing import NamedTuple

import netCDF4
import numpy as np
import yaml

from rbstudy.errors import ConfigError, InputError, RbstudyError, one_line
from rbstudy.inputs.reader import open_regular_file
from rbstudy.physics.time_grid import output_times
from rbstudy.pipeline.batches import Batch, batches_digest
from rbstudy.pipeline.chunks import ChunkedArchive
from rbstudy.pipeline.integrity import (
    HDF5_LOCK,
    StreamedChecksum,
    file_digest,
    hdf5_writer,
    nearly_full,
    netcdf_writer,
    part_digest,
    reseal_group,
    seal_archive,
    sidecar,
    sidecar_text,
    verify_archive,
)
from rbstudy.pipeline.variables import (
    COORDINATES,
    SCHEME_COORDINATES,
    VARIABLES,
    cf_attrs,
    variable_attrs,
)

__all__ = [
    "HDF5_LOCK",
    "SEARCH_FILE",
    "SEARCH_GROUP",
    "search_path",
    "put_group",
    "read_group",
    "Layout",
    "read_part",
    "write_text_atomic",
    "UnwritableFolder",
    "unwritable",
    "check_output_folder",
    "WRITE_REFUSALS",
    "consolidate",
    "global_attrs",
    "resolved_config",
    "grid_coordinates",
    "utc_now",
    "open_results",
    "part_complete",
    "archive_state",
    "write_part",
    "refresh_description",
    "decimal_grid",
    "COMPRESSION",
    "OWNER",
    "IDENTITY",
    "study_identity",
    "folder_claim",
    "make_folders",
    "remove_folders",
    "claim_folder",
    "inside",
    "source_text",
    "archive_dims",
]

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
# mkstemp creates files readable by their owner only; results are meant to be shared.
_FILE_MODE = 0o644
_LABELS = {"axis": ["x", "y", "z"], "component": ["x", "y", "z", "w"]}
# Compression of the consolidated archive's data variables: zlib (readable by every netCDF-4
# reader) after byte shuffling, which groups the slowly varying high bytes of neighbouring
# floats; level 4 gives nearly all of level 9's size at a fraction of its time.
COMPRESSION = {"zlib": True, "shuffle": True, "complevel": 4}
# Target size of an archive chunk (uncompressed): `case_chunks`.
CHUNK_BYTES = 2**18
# The file of a study folder that names the config (its file's resolved path and its text's
# SHA-256) whose study the folder holds: another config of the same name would replace its
# archive and parts.
OWNER = ".rbstudy-study"
# Where `sweep --find-step` keeps its probes (`rbstudy.pipeline.step_search`): the archive's
# netCDF group, sealed with it (`put_group`), once the search is done; until then the working
# file of the study folder, which an interrupted search resumes from.
SEARCH_GROUP = "search"
SEARCH_FILE = pathlib.Path("search") / "steps.nc"
# The global attribute of the archive and of each part that names the config of its study,
# as `OWNER` does (its two lines): the results identify their study without the record.
IDENTITY = "config_identity"
# Bytes of an owner record read at most: a resolved path and a digest.
_OWNER_BYTES = 2**13
# Attempts of `check_output_folder` and `make_folders` to write in a folder that a failed
# sweep, at the same instant, removes under them (each removes only the folders it made).
_CHECK_ATTEMPTS = 10
# An output interval with more decimals than this is no short decimal (0.1 / 3): its grid
# keeps the plain products.
_MAX_DECIMALS = 15
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


def source_text(version):
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


def utc_now():
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def global_attrs(study, command=None, started=None):
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


def resolved_config(study):
    """The study as YAML with every sweep expanded into explicit values (``study.yaml``)."""
    resolved = {
        "name": study.name,
        "title": study.title,
        **study.base,
        "output": {
            "interval": study.output_interval,
            "variables": list(study.variables),
            "accuracy_bound": study.accuracy_bound,
        },
        "sweep": {d.name: {axis.target: list(axis.values) for axis in d.axes} for d in study.dimensions},
        "cases": len(study.cases),
        "batches": [batch.id for batch in study.batches],
    }
    return yaml.safe_dump(resolved, sort_keys=False)


@dataclass(frozen=True)
class Layout:
    """What a part file needs to know of its study (small: it travels with every task)."""

    study: str
    variables: tuple
    n_times: int
    output_interval: float
    node_names: tuple
    identity: tuple  # `study_identity`

    @classmethod
    def of(cls, study):
        return cls(
            study=study.name,
            variables=study.variables,
            n_times=study.n_times,
            output_interval=study.output_interval,
            node_names=study.node_names,
            identity=study_identity(study),
        )


class PartTarget(NamedTuple):
    """Where a store task puts its batch: the study's `Layout`, the `Batch` and the path
    of its part file."""

    layout: Layout
    batch: Batch
    path: str

    @property
    def cases(self):
        return len(self.batch.cases)

    def write(self, values):
        """`write_part` of this batch's ``values``; the part's digest."""
        return write_part(self.layout, self.batch, values, self.path)


def decimal_grid(n_times, interval):
    """The output times (`rbstudy.physics.simulate.output_times`) as the archive labels them:
    each the double nearest its decimal value, ``0.35``, not ``35 * 0.01 =
    0.35000000000000003``, so that ``ds.sel(time=0.35)`` finds it. An interval with more
    than 15 decimals is left as the plain products."""
    times = output_times(n_times, interval)
    places = -decimal.Decimal(repr(float(interval))).as_tuple().exponent
    if places > _MAX_DECIMALS or times[-1] * 10.0**places >= 2.0**52:
        return times
    return np.round(times, places)  # exact: k * interval * 10^places is a whole number


def _fixed_coords(layout):
    """time, axis, component and node coordinates as (values, attrs)."""
    coords = {"time": (decimal_grid(layout.n_times, layout.output_interval), {})}
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


def grid_coordinates(study):
    """The coordinates of the swept dimensions: name -> (dims, values, attrs).

    A product dimension's coordinate is its axis; a zipped dimension gets an index coordinate
    and one auxiliary coordinate per axis. ``scheme`` and ``dt``, when not swept, are scalar
    coordinates, so that every dataset names both. Each scheme's nominal order and claimed
    invariants (`SCHEME_COORDINATES`) are auxiliary coordinates along ``scheme``.
    """
    coords = {}
    swept = {axis.target for dim in study.dimensions for axis in dim.axes}
    for name in ("scheme", "dt"):
        if name not in swept:  # then every run has the first run's
            value = getattr(study.cases.runs[0], name)
            coords[name] = (
                (),
                np.array(value, dtype=object if name == "scheme" else float),
                cf_attrs(*COORDINATES[name]),
            )
    coords.update(_scheme_claims(study, () if "scheme" not in swept else ("scheme",)))
    for dim in study.dimensions:
        if len(dim.axes) > 1:
            coords[dim.name] = (
                (dim.name,),
                np.arange(dim.size),
                {"long_name": "index along the zipped axes " + ", ".join(a.coordinate for a in dim.axes)},
            )
        for axis in dim.axes:
            attrs = cf_attrs(axis.units, axis.long_name)
            attrs["sweep_path"] = axis.target
            coords[axis.coordinate] = ((dim.name,), _coordinate_values(axis), attrs)
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
    coords = {}
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
        coords[name] = (along, np.asarray(values).reshape(shape), cf_attrs(units, long_name))
    return coords


def _write_part_file(nc, layout, batch, values):
    """The part file of ``batch`` into the open netCDF ``nc``: its variables ``values``
    (case first) along dim ``case``, whose coordinate is each case's position in the study
    (C order of the grid), uncompressed (a part lives until the archive is written). Written
    with netCDF4 directly: through xarray a part took 2-3 times as long, and the default
    study writes one per batch (docs/performance.md)."""
    nc.setncatts({"study": layout.study, "batch": batch.id, IDENTITY: "\n".join(layout.identity)})
    cases = np.array(batch.cases)
    nc.createDimension("case", len(cases))
    _create(nc, "case", ("case",), cases, {"long_name": "case number in the study"})
    for name, (coordinate, attrs) in _fixed_coords(layout).items():
        nc.createDimension(name, len(coordinate))
        _create(
            nc,
            name,
            (name,),
            coordinate.astype(object) if coordinate.dtype.kind == "U" else coordinate,
            attrs,
        )
    for name in layout.variables:
        _create(
            nc,
            name,
            ("case",) + VARIABLES[name].dims,
            np.asarray(values[name], dtype=VARIABLES[name].dtype),
            variable_attrs(name),
        )


def read_part(path, variables):
    """The case numbers and ``variables`` of the part file at ``path``, name -> array."""
    with HDF5_LOCK, netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        return {name: nc[name][...] for name in ("case", *variables)}


@contextmanager
def _temporary_beside(path):
    """A temporary path in ``path``'s folder, renamed to ``path`` on success, removed on failure."""
    path = pathlib.Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(handle)
    except OSError as error:
        raise unwritable(path.parent, error) from None
    try:
        yield temporary
        os.chmod(temporary, _FILE_MODE)
        _sync(temporary)  # the data on disk before the name points at it
        os.replace(temporary, path)
        _sync(path.parent)  # and the rename itself, so that a crash keeps one or the other
    except (OSError, RuntimeError) as error:
        _raise_if_full(path.parent, error)
        raise
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


# What a file system answers a write it refuses: read-only, immutable, not ours, full.
WRITE_REFUSALS = frozenset({errno.EROFS, errno.EPERM, errno.EACCES, errno.ENOSPC, errno.EDQUOT})
# What a file system answers a write that found no room: no blocks, or the user's quota spent.
_NO_SPACE = frozenset({errno.ENOSPC, errno.EDQUOT})


class UnwritableFolder(RbstudyError):
    """A folder whose file system refuses rbstudy's files (read-only, immutable, a path
    under a file, a system file system such as /proc)."""


def unwritable(folder, error, label=""):
    """The one-line error of ``folder`` refusing a write with the `OSError` ``error``:
    "no space left" (raised here) when its file system is (nearly) full, else an
    `UnwritableFolder` with the system's reason, to raise. ``label`` goes before the
    folder (``"--out "``)."""
    if error.errno != errno.EROFS:  # read-only media (an ISO image) report no free space
        _raise_if_full(folder, error)
    # a system file system (/proc) answers a new name with "No such file or directory"
    reason = (
        "its file system takes no new files"
        if error.errno == errno.ENOENT
        else error.strerror or one_line(error)
    )
    return UnwritableFolder(
        f"{label}{folder}: cannot write results there ({reason}); choose another folder with --out"
    )


def search_path(archive):
    """The step search's working file beside the archive at ``archive`` (`SEARCH_FILE`)."""
    return pathlib.Path(archive).parent / SEARCH_FILE


def check_output_folder(folder, label="--out "):
    """Refuse ``folder``, in one line, when rbstudy could not write there: a path that is, or
    lies under, a file, or a folder whose file system refuses a new file (read-only,
    immutable, /proc) or one of its missing names (too long). Called before a command prints
    or computes anything. It touches no folder another command may share: the missing
    folders are made, with a file in the last, inside a private folder of the nearest one
    that exists, which it removes whole (`_probe_under`). A failed sweep that removes that
    nearest folder under the check at the same instant makes it look again."""
    folder = pathlib.Path(folder)
    for attempt in range(1, _CHECK_ATTEMPTS + 1):
        place, under = folder.absolute(), False
        while not place.exists():
            place, under = place.parent, True
        if not place.is_dir():
            what = "is a file" if not under else f"lies under the file {place}"
            raise UnwritableFolder(f"{label}{folder}: {what}, not a folder; choose another folder with --out")
        try:
            _probe_under(place, folder.absolute().relative_to(place))
            return
        except OSError as error:
            # the nearest folder gone under this check (or /proc, which takes no new name:
            # it fails each time)
            if error.errno != errno.ENOENT or attempt == _CHECK_ATTEMPTS:
                raise unwritable(folder, error, label) from None


def _probe_under(place, missing):
    """Make the relative path ``missing`` (``.``: none) and a file in it inside a new private
    folder of the existing folder ``place``, then remove that folder whole: raises the
    `OSError` a write of those names in ``place`` meets."""
    private = pathlib.Path(tempfile.mkdtemp(dir=place, prefix=".rbstudy-probe-"))
    try:
        deepest = private / missing
        deepest.mkdir(parents=True, exist_ok=True)
        handle, _ = tempfile.mkstemp(dir=deepest)
        os.close(handle)
    finally:
        shutil.rmtree(private, ignore_errors=True)


def make_folders(folder):
    """Make ``folder`` and its missing parents; the folders this process made, outermost
    first (one that another process makes at the same instant is found, not made; one that a failed
    sweep that made it removes under it is made again). On a
    failure the folders it made are removed again."""
    made = []
    for attempt in itertools.count(1):
        missing, place = [], pathlib.Path(folder)
        while not place.exists():
            missing.append(place)
            place = place.parent
        try:
            for path in reversed(missing):
                try:
                    path.mkdir()
                    made.append(path)
                except FileExistsError:
                    pass  # made by another: a file there fails the next mkdir, or the caller
            return made
        except OSError as error:
            if not isinstance(error, FileNotFoundError) or attempt == _CHECK_ATTEMPTS:
                remove_folders(made)
                raise


def remove_folders(made):
    """Remove the folders `make_folders` made, innermost first, as long as they are empty:
    another command may be writing in them."""
    for path in reversed(made):
        try:
            path.rmdir()
        except OSError:
            return


def _raise_if_full(folder, error=None):
    """The one-line error of a full disk, when the write that failed with ``error`` said so
    (ENOSPC: `rbstudy.pipeline.integrity` turns HDF5's errors on a nearly full disk into
    one, measured before the temporary was truncated) or the file system of ``folder`` (or
    of its nearest existing ancestor) is (nearly) full (`integrity.nearly_full`)."""
    if getattr(error, "errno", None) not in _NO_SPACE and not nearly_full(folder):
        return
    mount = pathlib.Path(folder).absolute()
    while not os.path.ismount(mount):
        mount = mount.parent
    raise RbstudyError(
        f"{folder}: no space left on the file system at {mount}; free space and "
        "rerun the same command (a sweep keeps its finished parts and resumes)"
    ) from None


def _sync(path):
    """fsync a file or a folder: a machine crash after a rename must not leave the new name
    on an empty or partial file (the rename can reach the disk before the data)."""
    handle = os.open(path, os.O_RDONLY)
    try:
        os.fsync(handle)
    finally:
        os.close(handle)


def open_results(path, variables=None, reduced=None):
    """Load a results or part file, ``time`` in seconds from the start of the run.

    ``variables`` (optional) loads only those data variables (and the coordinates): the
    summary of a large study needs its per-case scalars, not its trajectories. ``reduced``
    (optional, name -> ``"max"`` or ``"last"``) loads those time series of them reduced
    along ``time``, slab by slab: the largest sample (NaN where any is), or the last one
    (``time`` its scalar coordinate). A million cases' two series of 11 samples took 176 MB
    whole and twice that while read.
    """
    import xarray as xr  # here: a sweep's workers and its forecast never read a dataset (0.3 s)

    skip = None if variables is None else [name for name in VARIABLES if name not in variables]
    with HDF5_LOCK, xr.open_dataset(path, decode_times=False, drop_variables=skip) as dataset:
        series = {
            name: _reduced_along_time(dataset[name], how)
            for name, how in (reduced or {}).items()
            if name in dataset and "time" in dataset[name].dims
        }
        rest = dataset.drop_vars(list(series))
        if series and not any("time" in variable.dims for variable in rest.data_vars.values()):
            rest = rest.drop_vars("time")  # the last sample's time would collide with it
        return rest.load().assign(series)


# Bytes of a slab read at a time by `_reduced_along_time`.
_REDUCTION_SLAB_BYTES = 2**23


def _reduced_along_time(variable, how):
    """``variable`` (lazy) reduced along ``time``: ``"max"`` (NaN propagated) or ``"last"``."""
    if how == "last":
        return variable.isel(time=-1).load()
    if how != "max":
        raise ValueError(f"reduce along time by 'max' or 'last', not {how!r}")
    if not variable.ndim or variable.dims[0] == "time":
        return variable.max("time", skipna=False).load()
    per_position = variable.size // variable.shape[0] * variable.dtype.itemsize
    step = max(1, _REDUCTION_SLAB_BYTES // max(1, per_position))
    first = variable.dims[0]
    largest = np.concatenate(
        [
            variable.isel({first: slice(start, start + step)}).max("time", skipna=False).values
            for start in range(0, variable.shape[0], step)
        ]
    )
    return variable.isel(time=0, drop=True).copy(data=largest)


def inside(folder, name):
    """``folder / name``, refused unless it resolves inside ``folder``: the last guard of
    every file a command names after what it read (a figure is named after the archive's
    study), whatever let such a name through."""
    folder = pathlib.Path(folder)
    path = folder / name
    if not path.resolve().is_relative_to(folder.resolve()):
        raise InputError(
            f"{name!r} would be written outside it, at {path.resolve()}",
            "a study name holds letters, digits, '-' and '_' only",
            str(folder),
        )
    return path


def refresh_description(path, attrs):
    """Replace the global attributes of the archive at ``path`` (its title, config text and
    provenance) without touching its data: a changed title or comment needs no recomputation.
    Written through a copy and a rename, like every other write (`_rewritten`)."""
    with _rewritten(path) as temporary, netcdf_writer(temporary, "a") as nc:
        nc.setncatts(attrs)


@contextmanager
def _rewritten(path):
    """A copy of the archive at ``path`` under a temporary name beside it, to change, then
    renamed over it (under `HDF5_LOCK`, a Ctrl-C held till then): a file system that refuses
    the copy or the rename (read-only, immutable, full) is one line naming the folder."""
    try:
        with _ctrl_c_held(), _temporary_beside(path) as temporary, HDF5_LOCK:
            shutil.copyfile(path, temporary)
            yield temporary
    except OSError as error:
        if error.errno in WRITE_REFUSALS:
            raise unwritable(pathlib.Path(path).parent, error) from None
        raise


def put_group(path, group, dataset):
    """Put the xarray ``dataset`` into the sealed archive at ``path`` as its netCDF group
    ``group`` (replacing one of that name), sealed with the archive's own checksums
    (`rbstudy.pipeline.integrity.reseal_group`): the step search's probes travel in the
    archive, and ``verify`` proves them. Written through a copy and a rename (`_rewritten`)."""
    with _rewritten(path) as temporary:
        with hdf5_writer(temporary) as h5file:
            if group in h5file:  # netCDF4 cannot remove a group; HDF5 unlinks it
                del h5file[group]
        dataset.to_netcdf(temporary, mode="a", group=group)
        with netcdf_writer(temporary, "a") as nc:
            reseal_group(nc, group)


def read_group(path, group):
    """The netCDF group ``group`` of the file at ``path`` as a loaded xarray dataset; None
    where the file has no such group (an archive without a step search)."""
    import xarray as xr  # here, as in `open_results`

    with HDF5_LOCK:  # the library is not thread-safe: one file at a time in a process
        with netCDF4.Dataset(path) as nc:
            if group not in nc.groups:
                return None
        return xr.load_dataset(path, group=group)


def archive_state(path, study):
    """What the archive at ``path`` is to ``study``: ``("absent", [])``, ``("outdated", [])``
    (another config or code: its ``batches`` differ), ``("damaged", problems)`` (a variable
    no longer matches its checksum, `rbstudy.pipeline.integrity`) or ``("current", [])``:
    then a rerun has nothing to do."""
    if not pathlib.Path(path).exists():
        return "absent", []
    try:
        with HDF5_LOCK, netCDF4.Dataset(path) as nc:
            batches = nc.getncattr("batches")
    except (OSError, AttributeError, RuntimeError):
        return "damaged", ["it cannot be read as netCDF"]
    if batches != batches_digest(study.batches):
        return "outdated", []
    with HDF5_LOCK:
        problems = verify_archive(path).problems
    return ("damaged", list(problems)) if problems else ("current", [])


def study_identity(study):
    """Who ``study`` is to its folder (`OWNER`, `IDENTITY`): its config file's resolved path
    and the SHA-256 of the config's text. Two identities are one study when either matches:
    the same file edited, or the same text moved to another file."""
    return (str(pathlib.Path(study.path).resolve()), hashlib.sha256(study.text.encode()).hexdigest())


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


def _results_owner(folder, study):
    """The identity of another config named by ``folder``'s archive or parts, or None when
    none names one, or one names ``study`` (parts of every age: the file edited since some
    of them were written is still the same study)."""
    mine, other = set(study_identity(study)), None
    for path in [folder / f"{study.name}.nc", *sorted((folder / "parts").glob("*.nc"))]:
        identity = _results_identity(path)
        if identity is not None and set(identity) & mine:
            return None
        other = other or identity
    return other


def folder_claim(root, study, force=False):
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
    kept = len(list((folder / "parts").glob("*.nc")))
    archive = "its archive and " if (folder / f"{study.name}.nc").exists() else ""
    return (
        f"{study.name}: --force replaces the study of {owner[0]} in {folder} ({archive}"
        f"{kept} kept part{'' if kept == 1 else 's'})"
    )


def claim_folder(folder, study):
    """Record ``study``'s config as the one whose study ``folder`` holds (`folder_claim`
    must have let it). A rename replaces whatever is in the record's place but a folder,
    which is not rbstudy's to remove: then the archive and the parts name the study alone."""
    identity = study_identity(study)
    path = pathlib.Path(folder) / OWNER
    if path.is_dir() and not path.is_symlink():
        return
    if _recorded_identity(path) != identity:
        write_text_atomic("\n".join(identity) + "\n", path)


def part_complete(path, batch):
    """The digest of ``path`` when it is an intact part of ``batch`` (its bytes match the
    digest stored when it was written, its id and its cases match), else None.

    A rename makes a part appear whole, but a crash of the machine (not of the process) can
    leave an empty or truncated file, and a disk or a hand can change one: such a part is
    recomputed, never trusted.
    """
    digest = part_digest(path)
    if digest is None:
        return None
    try:
        with HDF5_LOCK, netCDF4.Dataset(path) as nc:
            same = nc.getncattr("batch") == batch.id and np.array_equal(
                nc["case"][:], np.asarray(batch.cases)
            )
    except (OSError, KeyError, AttributeError, IndexError, RuntimeError):
        return None
    return digest if same else None


def write_part(layout, batch, values, path):
    """Write the part of ``batch`` (its variables ``values``) to ``path`` through a temporary
    file and a rename, then its digest beside it; returns the digest."""
    with _temporary_beside(path) as temporary, HDF5_LOCK:
        with netcdf_writer(temporary) as nc:
            _write_part_file(nc, layout, batch, values)
        digest = file_digest(temporary)
    # after the rename: a kill between the two leaves a part without digest, recomputed
    try:
        write_text_atomic(sidecar_text(digest, path), sidecar(path))
    except RbstudyError:  # a full disk: no part is left without its digest, half finished
        os.remove(path)
        raise
    return digest


def write_text_atomic(text, path):
    with _temporary_beside(path) as temporary:
        pathlib.Path(temporary).write_text(text)


def write_dataset_atomic(dataset, path):
    """Write an xarray ``dataset`` to the netCDF file ``path`` through a temporary beside it:
    a reader never sees half a file (the conformance scorecard, the step search's probes)."""
    with _ctrl_c_held(), _temporary_beside(path) as temporary, HDF5_LOCK:
        dataset.to_netcdf(temporary)


@contextmanager
def _ctrl_c_held():
    """Hold a Ctrl-C until the block ends, then raise it: xarray's ``to_netcdf``,
    interrupted between taking its netCDF lock and releasing it, waits for that lock
    forever as it closes the file (a sweep --find-step, interrupted, hung so). Only the
    main thread receives Python's signals; elsewhere the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda number, frame: caught.append(number))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught and callable(previous):  # Python's own raises KeyboardInterrupt
        previous(signal.SIGINT, None)


def case_chunks(grid_shape, own_shape, itemsize):
    """Chunk shape of an archive variable: whole along its own dimensions (time, node,
    axis, ...), and along the grid's dimensions, from the last, as many cases as keep a
    chunk near `CHUNK_BYTES`. The archive is written part by part, and a part holds whole
    cases: chunks of whole cases are filled by one part, each compressed once. netCDF's
    default chunks cut across cases, so that every part decompressed and compressed again
    the chunks it shared with the others (10,000 cases: 35 s of 50 in consolidation)."""
    chunk = [max(1, size) for size in own_shape]  # netCDF refuses a chunk of length 0
    room = max(1, CHUNK_BYTES // max(1, itemsize * math.prod(own_shape)))
    grid_chunk = []
    for size in reversed(grid_shape):
        take = max(1, min(size, room))
        grid_chunk.insert(0, take)
        room //= take
    return tuple(grid_chunk + chunk)


def _create(nc, name, dims, values=None, attrs=None, dtype=None, grid_rank=0):
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


def consolidate(study, arriving, target, attrs, advance=lambda: None):
    """Write ``<study>.nc`` from its parts as they arrive: ``arriving`` yields (path, digest)
    of the part of each batch of ``study.batches``, in their order, and may wait for a
    part still being computed (the archive is written while later batches run). netCDF4
    defines the archive; its chunks are then filled from the parts and compressed on every
    core (`ChunkedArchive`, through h5py). ``advance()`` after each part; then the archive
    is sealed with its checksums, hashed as the values are written, and the parts' digests."""
    shape = study.shape
    parts = zip(study.batches, arriving, strict=True)
    # the archive is defined once the first part is there, so that a disk too small for one
    # part fails on the part alone (the archive's metadata, written at once, takes its pages)
    first = next(parts, None)
    with _temporary_beside(target) as temporary:
        with netcdf_writer(temporary) as nc, HDF5_LOCK:
            defined = _define_archive(nc, study, attrs)
        with hdf5_writer(temporary) as h5file:
            archive = ChunkedArchive(h5file)
            try:
                targets = {
                    name: (archive.variable(name, grid_rank), along, stream)
                    for name, (grid_rank, along, stream) in defined.items()
                }
                part_digests = []
                for batch, (path, digest) in itertools.chain([first] if first else [], parts):
                    _copy_part(targets, read_part(path, study.variables), shape)
                    part_digests.append([batch.id, digest])
                    advance()
                archive.finish(variable for variable, _, _ in targets.values())
            finally:
                archive.close()
        seal_archive(temporary, part_digests, {name: stream for name, (_, _, stream) in defined.items()})


def _define_archive(nc, study, attrs):
    """Create the archive's dimensions, coordinates and (empty) variables in the open ``nc``;
    name -> (how many of its dimensions are the grid's, whether it lies along each grid
    dimension, its `StreamedChecksum`) of the output variables."""
    grid = grid_coordinates(study)
    nc.setncatts(attrs)
    for dim in study.dimensions:
        nc.createDimension(dim.name, dim.size)
    fixed = _fixed_coords(Layout.of(study))
    for name, (values, _) in fixed.items():
        nc.createDimension(name, len(values))
    for name, (dims, values, coord_attrs) in grid.items():
        _create(nc, name, dims, values, coord_attrs)
    for name, (values, coord_attrs) in fixed.items():
        _create(
            nc,
            name,
            (name,),
            values.astype(object) if values.dtype.kind == "U" else values,
            coord_attrs,
        )
    targets = {}
    for name in study.variables:
        along = archive_dims(study, name)
        attrs_ = variable_attrs(name)
        # the auxiliary coordinates (zipped axes, unswept scheme and dt, the schemes'
        # claims) that CF readers attach to it: those along its dimensions
        auxiliary = [
            coordinate
            for coordinate, (dims, _, _) in grid.items()
            if dims != (coordinate,) and set(dims) <= set(along)
        ]
        if auxiliary:
            attrs_["coordinates"] = " ".join(auxiliary)
        grid_rank = len(along) - len(VARIABLES[name].dims)
        variable = _create(nc, name, along, attrs=attrs_, dtype=VARIABLES[name].dtype, grid_rank=grid_rank)
        targets[name] = (
            grid_rank,
            tuple(d.name in along[:grid_rank] for d in study.dimensions),
            StreamedChecksum(variable, grid_rank),
        )
    return targets


def _block(cases, shape):
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


def archive_dims(study, name):
    """The dimensions of variable ``name`` in ``study``'s archive: the swept ones (a
    variable of the scene alone: those along which the scene changes), then its own."""
    grid = study.scene_dims if VARIABLES[name].per_scene else tuple(d.name for d in study.dimensions)
    return grid + VARIABLES[name].dims


def _copy_part(targets, part, shape):
    """Copy one part's cases (`read_part`) into the consolidated variables ``targets``: name
    -> (its chunk writer, `ChunkedArchive.variable`; whether it lies along each grid
    dimension; its `StreamedChecksum`, fed what is written). A part holds a value per
    case; a variable of the scene alone takes its cases' values at the first position of the
    dimensions it does not lie along (the same at every other)."""
    cases = part["case"]
    if not shape:  # a one-case study
        for name, (variable, _, _) in targets.items():
            variable.write((), part[name][0])
        return
    block = _block(cases, shape)
    # else slabs of consecutive cases: a batch cut from a long grid (one scheme and dt, 510 of
    # 100 x 1,000 spins and tilts) starts and ends inside a row; written case by case, such
    # a part took 0.5 s (1e5 cases: 100 s of 178)
    slabs = (
        [block]
        if block is not None
        else [
            (index, tuple(piece.stop - piece.start for piece in index))
            for run in np.split(cases, np.flatnonzero(np.diff(cases) != 1) + 1)
            for index in _slabs(int(run[0]), int(run[-1]) + 1, shape)
        ]
    )
    for name, (variable, along, stream) in targets.items():
        values, start = part[name], 0
        for index, sizes in slabs:
            count = math.prod(sizes)
            block = values[start : start + count].reshape(sizes + values.shape[1:])
            kept = tuple(where for where, keep in zip(index, along, strict=True) if keep)
            written = block[tuple(slice(None) if keep else 0 for keep in along)]
            variable.write(kept, written)
            stream.wrote(kept, written)
            start += count


def _slabs(first, stop, shape):
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
