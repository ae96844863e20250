"""The largest step that meets the accuracy bound, searched (``rbstudy sweep --find-step``).

A sweep answers at the steps it swept: when its largest ``dt`` meets the bound, a larger
one may as well, and the recommendation is capped by the grid. The search answers per
*group*, a scheme at one value of every other swept axis, starting from the grid's own
verdicts (the archive's ``accuracy``): ``lo``, the group's largest accurate swept step, and
``hi``, the smallest step above it that is not accurate (inaccurate, failed or unjudged).

- Bracketing: without a ``hi``, the step is doubled (its step count over the duration
  halved) until a probe is not accurate, or the whole duration is one step.
- Bisection: the geometric mean of ``lo`` and ``hi``, until ``hi / lo - 1`` is within the
  tolerance, or their step counts are adjacent.

Steps divide the duration (``dt = duration / n``): a run ends on it. A probe whose step
divides ``output.interval`` is judged at the study's samples, any other at every step (its
own samples: a step longer than the interval has no sample between). A probe is one case of
the study at another step, run and judged as the sweep runs and judges its cases (the same
`compute_batch`: kernels, references, verdict, calibrated cost).

Bisection assumes one crossing between ``lo`` and ``hi``: the answer is a step that meets
the bound, with a larger step within the tolerance that does not; a larger step still may
meet it again (an error that wraps round). The study-wide answer, the least found step of a
scheme over the other axes' values, is run at every value before it is named.

The finished search is kept in the archive, as its netCDF group ``search``
(`rbstudy.archive.layout.SEARCH_GROUP`, sealed with the archive's checksums: ``verify``
proves it): the probes (dimension ``probe``), each group's answer (``group``) and each
scheme's study-wide one (``scheme_searched``), which `rbstudy.analysis.searched` tells in
words. Until it is done, the probes are rewritten after every batch to the study folder's
working file ``search/steps.nc`` (`rbstudy.archive.folder.SEARCH_FILE`), removed once the
archive holds them, as the parts are. A rerun of the same study and code (to any tolerance)
reuses the probes of both, so an interrupted search resumes where it stopped; a rebuilt
archive (``--force``, or found damaged) starts it again.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import xarray as xr

from rbstudy.archive.folder import StudyFolder
from rbstudy.archive.ids import batches_digest, canonical_id
from rbstudy.archive.layout import CommonStep
from rbstudy.archive.provenance import utc_now
from rbstudy.archive.variables import ACCURATE, COORDINATES, SEARCH_VARIABLES, cf_attrs, variable_attrs
from rbstudy.numerics.machine import default_threads
from rbstudy.numerics.state import OK
from rbstudy.physics.time_grid import output_count, steps_per
from rbstudy.pipeline.calibration import calibrate, step_cost
from rbstudy.pipeline.execute import BatchJob, compute_batch, compute_references
from rbstudy.schemes import get_scheme

if TYPE_CHECKING:  # the types alone
    from rbstudy.pipeline.config import StudyConfig
    from rbstudy.pipeline.grid import Run
    from rbstudy.pipeline.progress import Progress

__all__ = ["SEARCH_TOLERANCE", "Search", "search_steps"]

# Default relative width of the final bracket: the answer and a step at most 5% larger that
# fails, so that 1.1 times the answer fails too where the error grows with the step.
SEARCH_TOLERANCE = 0.05
# What a probe's run gives: the archive's names for the case's verdict and cost.
_PROBE_VARIABLES = ("status", "accuracy", "n_steps", "step_seconds")
# What the probes file keeps of each probe, along ``probe``.
_PROBE_COLUMNS = ("case", "steps", "scheme", "dt", "output_interval", *_PROBE_VARIABLES)


@dataclass(frozen=True)
class Search:
    """A finished search, per group (g,) in C order of the study's dimensions without
    ``dt``: ``scheme`` (g,) names; ``case`` (g,) a grid case of the group (its scene and
    options); ``grid_dt`` (g,) its largest accurate swept step (NaN: none, not searched);
    ``found_dt`` (g,) the largest step found to meet the bound (NaN: none); ``failing_dt``
    (g,) the smallest step above it that does not (NaN: the whole duration meets it);
    ``found_seconds`` (g,) a case's calibrated kernel seconds at ``found_dt``;
    ``labels`` the other axes' values of each group (coordinate -> value); ``common``
    scheme -> its `CommonStep` (a scheme is missing where no step met the bound at every
    value of the other axes);
    ``adaptive`` the names of the study's adaptive schemes (not searched); ``probes`` the
    probes run or reused,
    a dataset along ``probe``; ``reused`` how many were reused; ``tolerance`` the relative
    width of the final brackets."""

    scheme: np.ndarray
    case: np.ndarray
    grid_dt: np.ndarray
    found_dt: np.ndarray
    failing_dt: np.ndarray
    found_seconds: np.ndarray
    labels: list[dict[str, Any]]
    common: dict[str, CommonStep]
    adaptive: tuple[str, ...]
    probes: xr.Dataset
    reused: int
    tolerance: float


def _identity(study: StudyConfig) -> str:
    """What a probe's verdict depends on: the study's batches (config, grid, code); not the
    tolerance, which only says which probes to run."""
    return canonical_id({"batches": batches_digest(study.batches)})


def _grid(study: StudyConfig, dataset: xr.Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """The study's grid verdicts as (groups, dt) arrays: accurate (bool), case numbers, and
    the swept steps (dt,) ascending; with the dimension names of the groups."""
    names = [d.name for d in study.dimensions]
    cases = np.arange(len(study.cases)).reshape(study.shape)
    accurate = (dataset["accuracy"].transpose(*names).values == ACCURATE) & (
        dataset["status"].transpose(*names).values == OK
    )
    if "dt" in names:
        k = names.index("dt")
        dts = np.asarray(dataset["dt"].values, dtype=float)
        accurate, cases = np.moveaxis(accurate, k, -1), np.moveaxis(cases, k, -1)
        group_dims = names[:k] + names[k + 1 :]
    else:
        dts = np.array([study.cases.runs[0].dt])
        accurate, cases = accurate[..., None], cases[..., None]
        group_dims = names
    return accurate.reshape(-1, len(dts)), cases.reshape(-1, len(dts)), dts, group_dims


def _steps(study: StudyConfig, dt: float) -> int:
    """The whole number of steps ``dt`` takes over the study's duration."""
    return steps_per(study.duration, dt, "dt", "duration")


class _Probes:
    """The probes of a search: those kept from an earlier run of it, those run now, keyed by
    (case, steps); written to the study folder's working file after every batch."""

    def __init__(self, study: StudyConfig, folder: StudyFolder, identity: str, force: bool):
        self.study, self.identity = study, identity
        self.folder = folder  # the `StudyFolder` of the search
        self.rows, self.reused = {}, 0
        if not force:  # a finished search's, in the archive, and an interrupted one's since
            self.rows = _kept_rows(self.folder, identity, working=False) | _kept_rows(
                self.folder, identity, working=True
            )
        self.kept = set(self.rows)

    def verdicts(self, wanted: Sequence[tuple[int, int]], progress: Progress | None) -> list[bool]:
        """Whether each (case, steps) of ``wanted`` meets the bound, running those not kept."""
        missing = sorted({key for key in wanted if key not in self.rows})
        self.reused += len({key for key in wanted if key in self.kept})
        self.kept -= set(wanted)
        by_run: dict[tuple[str, int], list[int]] = {}
        for case, steps in missing:
            by_run.setdefault((self._scheme(case), steps), []).append(case)
        for (scheme, steps), cases in sorted(by_run.items()):
            self._run(scheme, steps, np.asarray(cases))
            self.write()
            if progress is not None:
                progress.advance(len(cases))
        return [self.rows[key]["accuracy"] == ACCURATE and self.rows[key]["status"] == OK for key in wanted]

    def _scheme(self, case: int) -> str:
        cases = self.study.cases
        return cases.runs[cases.run_rows[case]].scheme

    def _run(self, scheme: str, steps: int, cases: np.ndarray) -> None:
        """Run the grid ``cases`` (all of ``scheme``) at ``steps`` steps over the duration."""
        study = self.study
        dt = study.duration / steps
        interval = study.output_interval if _divides(study, steps) else dt
        n_times = output_count(study.duration, interval)
        scene_rows = study.cases.scene_rows[cases]
        distinct, position = np.unique(scene_rows, return_inverse=True)
        table = study.cases.scenes
        references = compute_references(table, distinct, n_times, interval)
        runs = [study.cases.runs[r] for r in study.cases.run_rows[cases]]
        cost = step_cost(get_scheme(scheme), runs[0].options)
        job = BatchJob(
            scheme=scheme,
            dt=dt,
            output_interval=interval,
            scene_rows=scene_rows,
            options=np.array([get_scheme(scheme).option_row(run.options) for run in runs]),
            variables=_PROBE_VARIABLES,
            accuracy_bound=study.accuracy_bound,
            references=np.stack([np.zeros_like(position), position.reshape(-1)], axis=1),
            step_cost=(cost.seconds, cost.uncertainty),
        )
        values = compute_batch(job, table, [references], default_threads())
        for k, case in enumerate(cases):
            self.rows[(int(case), steps)] = {
                "case": int(case),
                "steps": steps,
                "scheme": scheme,
                "dt": dt,
                "output_interval": interval,
                **{name: values[name][k].item() for name in _PROBE_VARIABLES},
            }

    def _probes(self) -> xr.Dataset:
        keys = sorted(self.rows)
        columns = {
            name: ("probe", np.array([self.rows[key][name] for key in keys])) for name in _PROBE_COLUMNS
        }
        columns["scheme"] = ("probe", np.array(columns["scheme"][1], dtype=object))
        probes = xr.Dataset(columns)
        probes.attrs.update(
            {
                "title": f"{self.study.title}: the step search's probes",
                "study": self.study.name,
                "accuracy_bound": self.study.accuracy_bound,
                "search_identity": self.identity,
                "batches": batches_digest(self.study.batches),  # as the archive's: the same study
                "history": f"{utc_now()} rbstudy sweep --find-step",
            }
        )
        return probes

    def dataset(self, search: Search | None = None) -> xr.Dataset:
        """The probes as a dataset along ``probe`` (in the order of their keys), with the
        groups' answers of a finished ``search``."""
        written = self._probes()
        if search is not None:
            written = written.assign(
                group_scheme=("group", np.array(search.scheme, dtype=object)),
                group_case=("group", search.case),
                grid_dt=("group", search.grid_dt),
                found_dt=("group", search.found_dt),
                failing_dt=("group", search.failing_dt),
                found_seconds=("group", search.found_seconds),
            )
            names = sorted(search.common)
            written = written.assign(
                study_scheme=("scheme_searched", np.array(names, dtype=object)),
                study_dt=("scheme_searched", np.array([search.common[n].dt for n in names], dtype=float)),
                study_seconds=(
                    "scheme_searched",
                    np.array([search.common[n].seconds for n in names], dtype=float),
                ),
                study_uncertainty=(
                    "scheme_searched",
                    np.array([search.common[n].uncertainty for n in names], dtype=float),
                ),
            )
            written.attrs["tolerance"] = search.tolerance
            written.attrs["adaptive_schemes"] = " ".join(search.adaptive)  # chose their own steps
            written.attrs["other_axes"] = " ".join(
                sorted({name for labels in search.labels for name in labels})
            )
        for name in map(str, written.data_vars):
            written[name].attrs.update(_attrs(name))
        return written

    def write(self) -> None:
        """The probes so far to the working file, which a rerun resumes from."""
        self.folder.write_search(self.dataset())

    def seal(self, search: Search) -> None:
        """The finished ``search`` into the archive, sealed with it, and the working file
        removed (`rbstudy.archive.folder.StudyFolder.seal_search`)."""
        self.folder.seal_search(self.dataset(search))


def _kept_rows(folder: StudyFolder, identity: str, working: bool) -> dict[tuple[int, int], dict[str, Any]]:
    """The probes kept by a search of ``identity`` in the archive of the `StudyFolder`
    ``folder`` or, ``working``, in its working file, keyed by (case, steps); none from a
    file of another search, or one that is damaged (truncated, emptied, overwritten: run
    again, and the file rewritten)."""
    try:
        kept = folder.read_search(working)
        if kept is None or kept.attrs.get("search_identity") != identity:
            return {}
        columns = {name: kept[name].values for name in _PROBE_COLUMNS}
        rows = [
            {name: values[k].item() for name, values in columns.items()} for k in range(kept.sizes["probe"])
        ]
    except (OSError, ValueError, KeyError, IndexError, RuntimeError):
        return {}
    return {(row["case"], row["steps"]): row for row in rows}


def _divides(study: StudyConfig, steps: int) -> bool:
    """Whether a step of ``steps`` over the duration divides the output interval."""
    return steps % (output_count(study.duration, study.output_interval) - 1) == 0


def _attrs(name: str) -> dict[str, Any]:
    """The CF attributes of the search's variable ``name``: the archive's own for what a probe
    shares with a case (its scheme and step, `_PROBE_VARIABLES`), else the table's (`SEARCH_VARIABLES`)."""
    if name in _PROBE_VARIABLES:
        return variable_attrs(name)
    return cf_attrs(*(COORDINATES[name] if name in COORDINATES else SEARCH_VARIABLES[name]))


def _next_steps(lo: int, hi: int, tolerance: float) -> int:
    """The step count to probe next in a group whose largest accurate step takes ``lo``
    steps and whose smallest failing one ``hi`` (0: none yet); 0 when the search is done."""
    if not hi:
        return lo // 2  # the step doubled (0: the whole duration in one step met the bound)
    if lo - hi <= 1 or lo / hi - 1 <= tolerance:
        return 0
    return min(max(round(math.sqrt(lo * hi)), hi + 1), lo - 1)


def search_steps(
    study: StudyConfig,
    dataset: xr.Dataset,
    folder: str | os.PathLike[str],
    tolerance: float = SEARCH_TOLERANCE,
    force: bool = False,
    progress: Progress | None = None,
) -> Search:
    """The `Search` of ``study`` from its archive's ``dataset`` (``accuracy``, ``status``),
    its probes kept in the study folder ``folder`` (`SEARCH_FILE`), under the study's lock;
    ``force``: the kept probes are run again. Adaptive schemes choose their own steps and
    are not searched."""
    accurate, cases, dts, group_dims = _grid(study, dataset)
    runs = study.cases.runs
    schemes = np.array([runs[study.cases.run_rows[row[0]]].scheme for row in cases], dtype=object)
    adaptive = tuple(sorted(name for name in set(schemes) if get_scheme(name).adaptive))
    searched = accurate.any(axis=1) & ~np.isin(schemes, adaptive)
    lo, hi, grid_dt = np.zeros(len(cases), int), np.zeros(len(cases), int), np.full(len(cases), math.nan)
    for g in np.flatnonzero(searched):
        best = np.flatnonzero(accurate[g]).max()
        grid_dt[g], lo[g] = dts[best], _steps(study, dts[best])
        above = np.flatnonzero(~accurate[g, best + 1 :])
        hi[g] = _steps(study, dts[best + 1 + above[0]]) if above.size else 0
    calibrate(set(schemes[searched]), progress)
    if progress is not None:
        progress.phase(
            f"{study.name}: searching the largest step meeting the bound", unit="probes", eta=False
        )
    study_folder = StudyFolder(folder, study)
    with study_folder.lock():
        probes = _Probes(study, study_folder, _identity(study), force)
        while True:
            wanted = {int(g): _next_steps(lo[g], hi[g], tolerance) for g in np.flatnonzero(searched)}
            wanted = {g: steps for g, steps in wanted.items() if steps}
            if not wanted:
                break
            keys = [(int(cases[g, 0]), steps) for g, steps in wanted.items()]
            for (group, steps), good in zip(wanted.items(), probes.verdicts(keys, progress), strict=True):
                if good:
                    lo[group] = steps
                else:
                    hi[group] = steps
        common = _common_steps(study, schemes, cases, lo, searched, probes, progress)
        result = Search(
            **_answers(study, dataset, group_dims, schemes, cases, grid_dt, lo, hi, searched, common),
            adaptive=adaptive,
            probes=probes.dataset(),
            reused=probes.reused,
            tolerance=tolerance,
        )
        probes.seal(result)  # under the lock, as every write of the folder
    return result


def _answers(
    study: StudyConfig,
    dataset: xr.Dataset,
    group_dims: list[str],
    schemes: np.ndarray,
    cases: np.ndarray,
    grid_dt: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    searched: np.ndarray,
    common: dict[str, tuple[int, np.ndarray]],
) -> dict[str, Any]:
    """The `Search` fields of the groups' final brackets (step counts ``lo`` met, ``hi``
    failed, 0: none) and the schemes' ``common`` steps (`_common_steps`)."""
    found = np.where(searched, study.duration / np.maximum(lo, 1), math.nan)
    failing = np.where(searched & (hi > 0), study.duration / np.maximum(hi, 1), math.nan)
    seconds = np.array([lo[g] * _step_seconds(study, cases[g, 0]) for g in range(len(cases))])
    return dict(
        scheme=schemes,
        case=cases[:, 0],
        grid_dt=grid_dt,
        found_dt=found,
        failing_dt=failing,
        found_seconds=np.where(searched, seconds, math.nan),
        labels=_group_labels(dataset, group_dims),
        common={
            name: _common_cost(study, cases, steps, members) for name, (steps, members) in common.items()
        },
    )


def _common_steps(
    study: StudyConfig,
    schemes: np.ndarray,
    cases: np.ndarray,
    lo: np.ndarray,
    searched: np.ndarray,
    probes: _Probes,
    progress: Progress | None,
) -> dict[str, tuple[int, np.ndarray]]:
    """Per scheme searched at every value of the other axes: the step count of its least
    found step, and its groups, once every group of it has met the bound at that step
    (probed where its own found step is larger); name -> (steps, groups)."""
    common = {}
    for name in sorted(set(schemes)):
        members = np.flatnonzero(schemes == name)
        if not searched[members].all():
            continue
        steps = int(lo[members].max())
        keys = [(int(cases[g, 0]), steps) for g in members if lo[g] != steps]
        if all(probes.verdicts(keys, progress)):
            common[name] = (steps, members)
    return common


def _common_cost(study: StudyConfig, cases: np.ndarray, steps: int, members: np.ndarray) -> CommonStep:
    """The `CommonStep` of ``steps`` steps at the groups ``members``: the cost the findings
    rank the grid's answers by."""
    costs = [
        step_cost(get_scheme(_run(study, cases[g, 0]).scheme), _run(study, cases[g, 0]).options)
        for g in members
    ]
    return CommonStep(
        dt=study.duration / steps,
        seconds=steps * float(np.mean([cost.seconds for cost in costs])),
        uncertainty=max(cost.uncertainty for cost in costs),
    )


def _run(study: StudyConfig, case: int) -> Run:
    """The `Run` (scheme, options, dt) of the grid case ``case``."""
    return study.cases.runs[study.cases.run_rows[case]]


def _step_seconds(study: StudyConfig, case: int) -> float:
    """The calibrated seconds of a body-step of the grid case ``case``'s scheme and options."""
    run = _run(study, case)
    return step_cost(get_scheme(run.scheme), run.options).seconds


def _group_labels(dataset: xr.Dataset, group_dims: list[str]) -> list[dict[str, Any]]:
    """The values of the other swept axes (not ``scheme``) of each group, coordinate ->
    value, in C order of ``group_dims``."""
    shape = [dataset.sizes[d] for d in group_dims]
    named = {
        d: [
            str(name)
            for name, coord in dataset.coords.items()
            if coord.dims == (d,) and name != d or name == d
        ]
        for d in group_dims
        if d != "scheme"
    }
    labels = []
    for index in np.ndindex(*shape):
        place = dict(zip(group_dims, index, strict=True))
        labels.append(
            {
                name: dataset[name].values[place[d]].item()
                for d, names in named.items()
                for name in names
                if not (len(names) > 1 and name == d)  # a zipped dimension's own index
            }
        )
    return labels
