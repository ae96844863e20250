"""The verbs that read study configs: ``validate`` checks them and forecasts their cost,
``sweep`` runs them, archives the results and prints the findings (and, with
``--find-step``, the step search).
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
from typing import TYPE_CHECKING

from rbstudy.commands.common import check_out, each_file, say
from rbstudy.commands.results import searched_lines, summary_text
from rbstudy.errors import ConfigError, RbstudyError, counted

if TYPE_CHECKING:  # for the hints alone: running a verb imports what it needs then
    from rbstudy.pipeline.cluster import ClusterFile, Where
    from rbstudy.pipeline.config import StudyConfig
    from rbstudy.pipeline.execute import StudyRun

__all__ = ["sweep", "validate"]


def validate(args: argparse.Namespace) -> int:
    """``rbstudy validate``: each config read and checked, and its cost forecast, without
    running it."""
    from rbstudy.pipeline.config import load_study

    _check_root(args.out)  # what the sweep would refuse before any study: --out no folder

    def checked(path):
        study = load_study(path, args.set)
        line = _costed(study, args, disk=True)  # the limits are checked even when quiet
        return "\n".join(_warning_lines(study)) if args.quiet else f"{path}: ok: {line}"

    return each_file(args.files, checked)


def sweep(args: argparse.Namespace) -> int:
    """``rbstudy sweep``: every config read and checked (and its folder, its cost) before any
    study runs; then each run, archived, and its findings printed (and its step search, with
    ``--find-step``)."""
    cluster = _cluster_checked(args)
    from rbstudy.archive.folder import StudyFolder
    from rbstudy.pipeline.cluster import Where

    studies = _studies_read(args)
    read_only = _study_folders(studies, args)
    where = Where(
        scheduler=args.scheduler,
        workers=args.workers,
        cluster=cluster,
        writer=args.writer,
        worker_wait=args.worker_wait,
    )
    # a folder of another config of the same name is refused before any study runs
    replaces = [StudyFolder.of(args.out, study).check_claim(args.force) for study in studies]
    lines = [_costed(study, args, disk=False) for study in studies]  # before any run
    for study, line, replaced in zip(studies, lines, replaces, strict=True):
        if not args.quiet and study.name not in read_only:  # nothing to forecast there
            say(line)
        if replaced:  # even when quiet: it says whose results the run deletes
            say(replaced)
        _run_and_tell(study, args, where)
    return 0


def _cluster_checked(args: argparse.Namespace) -> ClusterFile | None:
    """Refuse the sweep's options that cannot work together, and return the cluster of
    ``--cluster`` (None without one) once its file is read, the ``--scheduler`` reached and,
    for local workers, their forkserver started."""
    if args.workers is not None and args.workers < 1:
        raise RbstudyError(f"--workers: need at least 1, got {args.workers}")
    if not args.worker_wait > 0:
        raise RbstudyError(f"--worker-wait: need a number of seconds above 0, got {args.worker_wait}")
    if args.step_tolerance is not None and not args.find_step:
        raise RbstudyError("--step-tolerance is the step search's: add --find-step, or drop it")
    cluster = None
    if args.cluster:
        from rbstudy.pipeline.cluster import read_cluster_file

        cluster = read_cluster_file(args.cluster)
    if args.scheduler:
        from rbstudy.pipeline.cluster import check_scheduler

        check_scheduler(args.scheduler)  # before the forecast: a typo waited for it
    if not args.scheduler and (args.workers or (cluster and cluster.kind == "local")):
        # the local workers' forkserver imports rbstudy while this process reads the studies
        from rbstudy.pipeline.cluster import start_forkserver

        start_forkserver()
    return cluster


def _studies_read(args: argparse.Namespace) -> list[StudyConfig]:
    """Every config of the command read and checked before any runs, each with every
    ``--set`` and in ``--format``; two of one name refused."""
    from rbstudy.numerics.machine import return_free_memory
    from rbstudy.pipeline.config import load_study

    studies = [load_study(path, args.set) for path in args.files]
    if args.format is not None:
        studies = [dataclasses.replace(study, output_format=args.format) for study in studies]
    if args.find_step and any(study.output_format == "zarr" for study in studies):
        raise RbstudyError(
            "--find-step keeps its search in a netCDF archive: drop it, or sweep with --format netcdf"
        )
    return_free_memory()  # the reading's transients, which are large for a study of a million cases
    names = [study.name for study in studies]
    for study in studies:
        if names.count(study.name) > 1:
            raise ConfigError(
                f"{study.name!r} is also the name of another config of this command",
                "study names pick the results folder: rename one",
                source=study.path,
                key="name",
            )
    return studies


def _run_and_tell(study: StudyConfig, args: argparse.Namespace, where: Where) -> None:
    """Run ``study`` where ``where`` says, then print what the run did, its findings and its
    table, and its step search; a search refused (a read-only folder) is raised once the
    findings are told."""
    from rbstudy.analysis.findings import FINDINGS_REDUCED, FINDINGS_VARIABLES
    from rbstudy.archive.reader import open_archive
    from rbstudy.numerics.machine import return_free_memory
    from rbstudy.pipeline.execute import run_study, study_progress

    with study_progress(study, args.quiet) as progress:
        done = run_study(
            study, args.out, where=where, force=args.force, keep_parts=args.keep_parts, progress=progress
        )
        progress.phase(f"{study.name}: reading its findings")
        return_free_memory()  # what the run's threads freed, before the reading's peak
        # proven by this run: sealed as written, or verified before it was reused
        dataset = open_archive(done.path, FINDINGS_VARIABLES, verify=False, reduced=FINDINGS_REDUCED)
        return_free_memory()  # what the run and the reading left, before the findings
        summary = summary_text(dataset, wide=args.wide)
        searched, refused = [], None
        if args.find_step:
            try:
                searched = _find_step(study, dataset, done.path, args, progress)
            except RbstudyError as error:  # a read-only folder: the findings still told
                refused = error
    _tell_run(study.name, done)
    print(summary)
    if refused is not None:
        raise refused
    if searched:
        print()
        say("\n".join(searched))


def _tell_run(name: str, done: StudyRun) -> None:
    """What the run of study ``name`` did (``done``, `rbstudy.pipeline.execute.run_study`'s):
    what it repaired or removed, what it ran and reused, where it wrote."""
    if done.archive_problems:
        say(f"{name}: the archive was damaged ({done.archive_problems[0]}); rebuilt it")
    if done.damaged_parts:
        say(
            f"{name}: {counted(done.damaged_parts, 'damaged part')} (their bytes no longer "
            "match their checksums) recomputed"
        )
    if done.removed_parts:
        say(
            f"{name}: removed {counted(done.removed_parts, 'part file')} left beside its "
            "current archive, which holds "
            "them (--keep-parts keeps them)"
        )
    if done.up_to_date:
        say(f"{name}: {done.path} is up to date (the same config and code); --force recomputes it")
    else:
        say(
            f"{name}: {counted(done.computed, 'batch', 'batches')} run, {done.reused} reused, "
            f"{done.wall_seconds:.1f} s; wrote {done.path}"
        )
    if done.returned:
        say(
            f"{name}: {counted(done.returned, 'part')} written here from the values the "
            "workers sent back (they do not see the results folder)"
        )


def _find_step(study, dataset, archive, args, progress):
    """The lines of the step search of ``study`` (`rbstudy.pipeline.step_search`), from its
    archive's ``dataset``, its probes kept in the ``archive``."""
    from rbstudy.pipeline.step_search import SEARCH_TOLERANCE, search_steps

    folder = pathlib.Path(archive).parent
    tolerance = SEARCH_TOLERANCE if args.step_tolerance is None else args.step_tolerance
    search = search_steps(study, dataset, folder, tolerance, args.force, progress)
    probes = f"{counted(search.probes.sizes['probe'], 'probe')} ({search.reused} reused)"
    return [*searched_lines(archive, dataset), f"{probes}; kept in {archive}, group search"]


def _costed(study, args, disk):
    """The study's one-line estimate (and a line per note and warning of the study), after refusing
    it past the limits of ``args`` (and past the free disk under ``args.out`` when ``disk``:
    a sweep checks it once it knows which parts are already there)."""
    from rbstudy.pipeline.estimate import (
        check_disk,
        check_limits,
        describe,
        estimate,
        forecast_disk,
        zarr_advice,
    )

    for option, value in (("--max-body-steps", args.max_body_steps), ("--max-memory", args.max_memory)):
        if value is not None and not value > 0:
            raise RbstudyError(f"{option} takes a number above 0, got {value:g}")
    cost = estimate(study)
    max_memory = None if args.max_memory is None else args.max_memory * 2**20
    check_limits(study, cost, args.max_body_steps, max_memory)
    if disk:
        check_disk(study, forecast_disk(study, args.out), args.out)
    notes = [f"{study.path}: note: {note}" for note in study.notes]
    advice = zarr_advice(study, cost)
    lines = [describe(study, cost), *([advice] if advice else []), *notes, *_warning_lines(study)]
    return "\n".join(lines)


def _warning_lines(study):
    """What the reading accepted but a user should know (a regularised body, a knot
    mid-step), a line each."""
    return [f"{study.path}: warning: {warning}" for warning in study.warnings]


def _check_root(root):
    """Refuse the results root ``root`` (--out) in one line when it is no folder (a file, a
    device, a path under a file); return the `UnwritableFolder` error of a folder rbstudy
    cannot write (read-only), which a rerun whose archives are up to date needs no write
    of, or None."""
    from rbstudy.archive.files import UnwritableFolder

    try:
        check_out(root)
    except UnwritableFolder as error:
        if not pathlib.Path(root).is_dir():  # a file, under a file: no archive to find there
            raise
        return error
    return None


def _study_folders(studies, args):
    """Check --out and each study's folder in it before a sweep prints anything, and return
    the names of the studies whose folder cannot be written but holds an archive: a rerun
    may still find it up to date, which needs no write (`run_study` tells, or refuses in
    one line naming the folder). A folder that cannot be written is refused at once under
    --force, and where it holds no archive."""
    from rbstudy.archive.files import UnwritableFolder
    from rbstudy.archive.folder import StudyFolder

    root = pathlib.Path(args.out)
    refused = _check_root(root)
    read_only = set()
    for study in studies:
        folder = root / study.name
        try:
            check_out(folder, given=False)
        except UnwritableFolder as error:
            if args.force or not StudyFolder.of(root, study).archive.exists():
                raise (refused or error) from None
            read_only.add(study.name)
    return read_only
