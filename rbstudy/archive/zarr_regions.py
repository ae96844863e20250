"""A zarr store written where its values are computed: each batch's region by its worker.

With ``--workers``, ``--cluster`` or ``--scheduler``, a study archived as a zarr store
(`rbstudy.archive.zarr_store`) passes no part through one writer. Before any batch runs, the
client defines the working store, ``parts/<study>.zarr`` (`open_working`): every variable,
coordinate and attribute, no values. The worker that computes a batch writes its cases into
the store (`RegionTarget.write`, compressed there), then a small mark beside it,
``parts/<batch-id>.region``, with its digest beside that, as a part file has: the mark says
the batch is in the store of its generation, so a rerun resumes from the batches marked in
the store it finds (a mark of a store since removed and defined anew counts for nothing). At
the end the client seals the store (`finish_regions`: consolidated metadata, each file's
SHA-256, the marks' digests) and renames it into place as ``<study>.zarr``, its generation
dropped from its attributes.

Units (a shard, or a chunk where a variable has no shards: `zarr_store.unit_bounds`) do not
follow batches: a batch cut from the grid shares its first and last units with its
neighbours, and a variable of the scene alone has the same cells in every scheme's batch. A
unit is therefore read, merged and written under a lock of its own, held across the cluster
(the sweep's: `rbstudy.pipeline.cluster.scheduler_lock`, a lock of the scheduler, named
after the store's generation), so two workers never write one file at once, even a worker
left running by a stopped sweep and one of its rerun. Under the lock a worker first checks
that the store is still of its generation: a worker left running by a sweep whose store was
since defined anew (another config) writes nothing into it, but in the instant between that
check and its write (the client takes no unit's lock to define a store). Each file is written whole by
zarr through a temporary and a rename: a worker killed mid-write leaves the unit as it was
(and a ``*.partial`` file, removed before the seal), and its batch, unmarked, runs again.
The cells are the same whatever order the batches come in, so the store is the one
`zarr_store.consolidate_store` writes from parts.

A scheduler's lock expires when its holder stops renewing it (``distributed.scheduler.locks
.lease-timeout``, 30 s by default): a worker stalled that long inside one unit's write could
let another in. One unit's write is far shorter than that.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import hashlib
import json
import os
import pathlib
import uuid
from collections.abc import Callable, Iterable, Mapping
from contextlib import AbstractContextManager
from typing import Any, NamedTuple

import numpy as np

from rbstudy.archive.files import replace_folder, temporary_folder_beside, write_text_atomic
from rbstudy.archive.layout import Layout
from rbstudy.archive.parts import SIDECAR_SUFFIX, file_digest, part_digest, part_values, sidecar, sidecar_text
from rbstudy.archive.writer import Arrival, CopyTarget, copy_part
from rbstudy.archive.zarr_store import (
    define_store,
    dimensions_of,
    finish_store,
    refresh_store_description,
    store_attribute,
    store_attributes,
    unit_bounds,
    unit_pieces,
)

__all__ = [
    "MARK_SUFFIX",
    "RegionTarget",
    "finish_regions",
    "mark_generation",
    "open_working",
    "region_complete",
    "remove_marks",
    "working_generation",
]


# A batch's mark: its cases are in the working store.
MARK_SUFFIX = ".region"


# The working store's attribute naming its generation: set when the store is defined, written
# in each mark and in the name of each unit's lock; the sealed store has none.
GENERATION = "rbstudy_working_generation"


def working_generation(path: str | os.PathLike[str], batches_digest: str) -> str | None:
    """The generation of the working store at ``path`` when it was defined whole for batches
    of ``batches_digest`` (`rbstudy.archive.ids.batches_digest`), else None: the cells its
    marked batches wrote are theirs."""
    with contextlib.suppress(OSError, KeyError, ValueError, TypeError):
        attributes = store_attributes(path)
        if attributes["batches"] == batches_digest:
            return attributes[GENERATION]
    return None


def open_working(path: pathlib.Path, study: Any, attrs: dict[str, Any]) -> str:
    """The generation of the working store at ``path`` for ``study`` (global attributes
    ``attrs``): kept when it was defined for these very batches (a resumed run), else defined
    anew, empty, in a temporary folder renamed into place (a sweep killed while it defines the
    store leaves none), the marks of the store it replaces removed first."""
    generation = working_generation(path, attrs["batches"])
    if generation is not None:
        return generation
    remove_marks(path.parent)
    generation = uuid.uuid4().hex
    with temporary_folder_beside(path) as temporary:
        define_store(temporary, study, {**attrs, GENERATION: generation})
    return generation


def remove_marks(folder: pathlib.Path) -> None:
    """Remove the marks (and their digests) in ``folder``: of a working store gone, or sealed."""
    for mark in [*folder.glob(f"*{MARK_SUFFIX}"), *folder.glob(f"*{MARK_SUFFIX}{SIDECAR_SUFFIX}")]:
        mark.unlink(missing_ok=True)


class RegionTarget(NamedTuple):
    """Where a store task puts its batch when workers write the store: the study's `Layout`,
    the batch (a `rbstudy.pipeline.batches.Batch`: its ``id`` and ``cases``), the path of its
    mark, the working store's path, the grid's dimension names and shape, the lock of a unit
    (a function of its name, held across the cluster: a module-level function, so that it
    travels with the task; None: one process writes) and the store's generation (`GENERATION`).
    As a `rbstudy.archive.parts.PartTarget` (small: it travels with its task)."""

    layout: Layout
    batch: Any
    path: str
    store: str
    dims: tuple
    shape: tuple
    lock: Callable[[str], AbstractContextManager] | None
    generation: str

    @property
    def cases(self) -> int:
        return len(self.batch.cases)

    def write(self, values: Mapping[str, np.ndarray]) -> str:
        """This batch's ``values`` (name -> array, case first) into the store, then its mark;
        the mark's digest."""
        part = part_values(self.batch, self.layout.variables, values)
        _write_region(self, part)
        return _mark(self, part)


class StoreReplaced(RuntimeError):
    """The working store a batch was to be written to was defined anew since (another config
    or a rerun after it was lost): this batch's values belong to no store."""


def _write_region(target, part):
    """The cases of ``part`` (`part_values`) into their units of the store, each unit read,
    merged and written whole under its lock, once the store is found still of the target's
    generation (`StoreReplaced` if not)."""
    arrays = _opened(target.store, target.generation, tuple(target.layout.variables))
    writes = collections.defaultdict(list)  # (name, unit) -> [(positions inside, values)]
    targets = {}
    for name, array in arrays.items():
        along = tuple(dim in dimensions_of(array) for dim in target.dims)
        targets[name] = CopyTarget(_Collected(array, name, writes), along, None)
    copy_part(targets, part, target.shape)
    for (name, unit), pieces in writes.items():
        array = arrays[name]
        named = f"rbstudy-{target.generation}:{name}:{'.'.join(map(str, unit))}"
        with target.lock(named) if target.lock else contextlib.nullcontext():
            _check_generation(target)
            bounds = unit_bounds(array, unit)
            buffer = np.array(array[bounds])  # what earlier batches put there, else the fill
            for inside, block in pieces:
                buffer[inside] = block
            array[bounds] = buffer


@functools.lru_cache(maxsize=8)
def _opened(store, generation, names):
    """The arrays ``names`` of the working ``store`` of ``generation``, name -> zarr array,
    opened once in a process for all the batches it writes there (each opening reads and
    parses the array's metadata, a good share of a large study's time in zarr)."""
    import zarr  # here: a netCDF study's workers never load it

    group = zarr.open_group(store, mode="r+", zarr_format=3, use_consolidated=False)
    return {name: group[name] for name in names}


def _check_generation(target):
    """Raise `StoreReplaced` unless the store is the one of the target's generation."""
    with contextlib.suppress(OSError, KeyError, ValueError):
        if store_attribute(target.store, GENERATION) == target.generation:
            return
    raise StoreReplaced(f"{target.store}: defined anew since batch {target.batch.id} began; not written")


class _Collected:
    """One variable as `copy_part` writes it (``write(index, values)``): its values gathered
    by unit, to write each unit once."""

    def __init__(self, array, name, writes):
        self.array, self.name, self.writes = array, name, writes

    def write(self, index: tuple, values: np.ndarray) -> None:
        for unit, inside, block in unit_pieces(self.array, index, np.asarray(values)):
            self.writes[(self.name, unit)].append((inside, block))


def _values_digest(part):
    """SHA-256 of a batch's values as written (each array's name, type, shape and bytes)."""
    digest = hashlib.sha256()
    for name in sorted(part):
        array = np.ascontiguousarray(part[name])
        digest.update(f"{name} {array.dtype.str} {array.shape}\n".encode())
        digest.update(array.data)
    return f"sha256:{digest.hexdigest()}"


def _mark(target, part):
    """The mark of ``target``'s batch, written whole, then its digest beside it (as a part's:
    a mark without one is a batch stopped between the two, run again); the digest."""
    layout = target.layout
    text = json.dumps(
        {
            "study": layout.study,
            "batch": target.batch.id,
            "identity": list(layout.identity),
            "generation": target.generation,
            "values": _values_digest(part),
        },
        indent=1,
    )
    write_text_atomic(text, target.path)
    digest = file_digest(target.path)
    write_text_atomic(sidecar_text(digest, target.path), sidecar(target.path))
    return digest


def mark_generation(path: str | os.PathLike[str]) -> str | None:
    """The generation the mark at ``path`` names, None where it cannot be read."""
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        return json.loads(pathlib.Path(path).read_text())["generation"]
    return None


def region_complete(
    path: str | os.PathLike[str], batch: Any, layout: Layout, generation: str | None
) -> str | None:
    """The digest of the mark at ``path`` when it is intact and marks ``batch`` of the study
    of ``layout`` in the working store of ``generation`` (None: there is none), else None."""
    digest = part_digest(path)
    if digest is None or generation is None:
        return None
    try:
        said = json.loads(pathlib.Path(path).read_text())
        if (
            said["batch"] == batch.id
            and said["identity"] == list(layout.identity)
            and said["generation"] == generation
        ):
            return digest
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def finish_regions(
    study: Any,
    arriving: Iterable[Arrival],
    target: str | os.PathLike[str],
    attrs: dict[str, Any],
    advance: Callable[[], None] = lambda: None,
    *,
    working: pathlib.Path,
) -> None:
    """``<study>.zarr`` from the ``working`` store once every batch is in it: the contract of
    `rbstudy.archive.writer.consolidate` (``arriving`` yields the `Arrival` of each batch,
    its mark for its path, in the batches' order, once written; ``advance()`` after each), the working store
    given this run's global attributes ``attrs``, sealed with the marks' digests
    (`finish_store`) and renamed into place, then its generation dropped and the marks
    removed.

    The generation stays in the working store until it is in place: a sweep killed while it
    seals the store (its checksums read every file back, long at a million cases) resumes from every
    mark. Killed between the rename and the attributes' rewrite, the archive keeps the
    attribute, which no reader reads and no checksum covers."""
    part_digests = []
    for batch, (_, digest, _) in zip(study.batches, arriving, strict=True):
        part_digests.append([batch.id, digest])
        advance()
    generation = store_attribute(working, GENERATION)
    refresh_store_description(working, {**attrs, GENERATION: generation})
    finish_store(working, part_digests)
    replace_folder(working, target)
    refresh_store_description(target, attrs)
    remove_marks(pathlib.Path(working).parent)
