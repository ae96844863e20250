"""Batches and identity: cases of one scheme, time step and cost per step grouped into bounded
batches, each named by a hash of what its part file holds.

A batch is the unit of work for dask and of storage. Its id is ``<scheme>_dt<dt>_<hash>``, the
hash of the canonical JSON (numbers normalised) of what makes its cases: the study's scene
mapping, the grid, the batch's grid positions and runs (scheme, dt, options), the output grid,
the stored variables, `SCHEMA_VERSION` and the digest of rbstudy's sources: the same config
and code give the same ids, anything else new ids, never a silent mix.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from rbstudy.archive.ids import canonical_id
from rbstudy.numerics.sources import SOURCE_DIGEST

if TYPE_CHECKING:  # the types alone: this module stays numba-free
    from rbstudy.pipeline.axes import Dimension
    from rbstudy.pipeline.grid import Cases

__all__ = [
    "Batch",
    "plan_batches",
]


@dataclass(frozen=True)
class Batch:
    """Cases of one scheme, time step and cost per step, run as one dask task and stored as
    one part.

    id : ``<scheme>_dt<dt>_<hash>`` (module docstring). cases : positions in the study's case
    list. step_seconds : the cost of a body-step of its run (`plan_batches`' ``run_costs``;
    None when planned without them).
    """

    id: str
    scheme: str
    dt: float
    cases: tuple[int, ...]
    step_seconds: float | None = None


def plan_batches(
    cases: Cases,
    scene: Mapping[str, Any],
    dimensions: Sequence[Dimension],
    output_interval: float,
    variables: Sequence[str],
    max_cases: int,
    verdict: Mapping[str, Any] | None = None,
    run_costs: Sequence[float] | None = None,
    code_digests: Mapping[str, str | None] | None = None,
) -> tuple[Batch, ...]:
    """Group `rbstudy.pipeline.grid.Cases` ``cases`` by (scheme, dt) and, where the runs
    differ in it, by their cost per step (``run_costs``, one number per run of ``cases.runs``:
    a composition of order 8 takes 17 steps a step), in case order, into batches of at most
    ``max_cases``. Cases of one batch share its kernel time equally, so a batch never mixes
    costs.

    A batch's id hashes what its part holds and where it goes: the study's ``scene`` mapping
    and the grid (every dimension's axes and values), which with the cases' positions make
    their scenes (with the order of the nodes, which the part's node axis follows, and each
    node and load table file the scenes name, its name bound to its content's digest, so
    that swapping the contents of two swept files changes the ids); the runs
    of its cases (scheme, dt and the options that scheme has, so that another scheme's
    option, unless swept, leaves it alone); the output grid and the stored variables; what
    the stored verdicts depend on (``verdict``: the accuracy bound); and the source digest of
    rbstudy (a fixed bug never reuses old numbers), and for a plug-in's scheme the digest of
    its package's sources (``code_digests``: scheme -> digest or None). Reordering or
    extending an axis therefore gives new ids, never a part in the wrong cells. Planning is
    linear in the cases.
    """
    study_digest = canonical_id(
        {
            "scene": scene,  # hashed with sorted keys: the node order goes in on its own
            "nodes": list(cases.scenes.node_names),
            "tables": list(cases.scenes.tables),
            "grid": [[d.name, [[a.target, list(a.values)] for a in d.axes]] for d in dimensions],
            "output_interval": output_interval,
            "variables": list(variables),
            "verdict": verdict,
            "source": SOURCE_DIGEST,
        }
    )
    costs: Sequence[float | None] = run_costs if run_costs is not None else [None] * len(cases.runs)
    # (scheme, dt, cost) -> group, in order of first use
    keys: dict[tuple[str, float, float | None], int] = {}
    group_of_run = np.array(
        [
            keys.setdefault((run.scheme, run.dt, cost), len(keys))
            for run, cost in zip(cases.runs, costs, strict=True)
        ]
    )
    groups = group_of_run[cases.run_rows]
    order = np.argsort(groups, kind="stable")  # each group's cases in case order
    starts = np.searchsorted(groups[order], np.arange(len(keys) + 1))
    batches = []
    for (scheme, dt, cost), group in keys.items():
        members = order[starts[group] : starts[group + 1]]
        for start in range(0, len(members), max_cases):
            chunk = members[start : start + max_cases]
            runs = [cases.runs[row] for row in np.unique(cases.run_rows[chunk])]
            identity = {
                "positions": chunk.tolist(),
                "study": study_digest,
                "runs": [[run.scheme, run.dt, run.options] for run in runs],
            }
            code = (code_digests or {}).get(scheme)
            if code is not None:  # only then: the ids of rbstudy's own schemes stay as they were
                identity["code"] = code
            digest = canonical_id(identity)
            batches.append(
                Batch(
                    id=f"{scheme}_dt{dt:g}_{digest}",
                    scheme=scheme,
                    dt=dt,
                    cases=tuple(chunk.tolist()),
                    step_seconds=cost,
                )
            )
    return tuple(batches)
