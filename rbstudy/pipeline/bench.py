"""`rbstudy bench`: throughput of every scheme on the Abaqus top, printed, never asserted.

It runs kernels, so it sits in the pipeline, which may load them, and not in the analysis
layer, which reads archives and never loads numba.

For each scheme: the first-call compilation time, then body-steps per second at batch sizes
1, 100 and 10,000, on one thread and on all cores. Each measurement runs about
``BODY_STEPS`` body-steps (steps x bodies) and times the compiled batch call only; the rate is
the number of steps actually taken divided by that time; with ``repeat``, the best of that many
rounds of the whole table (other programs only ever slow a run, so the best is nearest the
figure of the code itself). For the adaptive `dop853` the
"steps" are those of the output grid at ``BENCH_DT`` (its own steps are fewer and longer), so
its figure is simulated time / BENCH_DT per second, comparable with the fixed-step schemes.
The time step is small so that the explicit first-order schemes, whose energy grows every step, stay
below the blow-up bound over the long single-body run; output is sampled every
``SAMPLE_EVERY`` steps as a study would.
"""

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from rbstudy.errors import RbstudyError, SchemeError, counted
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.inputs.yaml_file import parse_yaml
from rbstudy.numerics.driver import BatchOutput, run_batch
from rbstudy.numerics.machine import default_threads
from rbstudy.physics.scenes import Scene
from rbstudy.pipeline.progress import Progress
from rbstudy.schemes import SCHEMES, Scheme, get_scheme

__all__ = [
    "run_bench",
    "option_settings",
    "scheme_options",
    "abaqus_top_scene",
    "BODY_STEPS",
    "MAX_BODY_STEPS",
    "MAX_REPEAT",
]

BATCH_SIZES = (1, 100, 10_000)
BODY_STEPS = 10_000_000
# The most --body-steps may ask for: a figure of 1e9 body-steps is long to wait for even with
# the fastest scheme (six figures a scheme), and its single body keeps 1e6 samples (~100 MiB);
# 1e18 asked for 92 PiB of samples.
MAX_BODY_STEPS = 1_000_000_000
# The most runs a figure may be the best of: 100 runs of the default figure are minutes a scheme.
MAX_REPEAT = 100
BENCH_DT = 1e-4
SAMPLE_EVERY = 1_000
# dop853 is per case in Python: a short run says enough about its cost.
REFERENCE_STEPS = 2_000
# The width of a rate's column (characters): "1.260e+07" and a space either side.
_RATE = 12


def abaqus_top_scene(loads: Mapping[str, Any] | None = None) -> Scene:
    """The Abaqus force-free top of docs/theory.md s2 (I = 1, 1, 2; A = 0.25; w3 = 2 pi), or
    under ``loads`` (a config's ``loads`` mapping)."""
    return scene_from_mapping(
        {
            **({"loads": loads} if loads else {}),
            "body": {"mass": 1.0, "inertia": [1.0, 1.0, 2.0]},
            "initial": {
                "angular_velocity": {"body": [0.25, 0.0, 2.0 * math.pi]},
                "orientation": {"momentum_axis": [0.0, 0.0, 1.0]},
            },
            "duration": 2.0,
        },
        source="bench",
    )


def _rate(
    scheme: Scheme, scene: Scene, n_bodies: int, n_steps: int, threads: int, options: Mapping[str, Any]
) -> tuple[float, BatchOutput]:
    state0 = np.repeat(scene.state_row()[None, :], n_bodies, axis=0)
    params = np.repeat(scene.param_row()[None, :], n_bodies, axis=0)
    option_rows = np.repeat(scheme.option_row(options)[None, :], n_bodies, axis=0)
    out = run_batch(
        scheme,
        state0,
        params,
        option_rows,
        BENCH_DT,
        n_steps,
        min(SAMPLE_EVERY, n_steps),
        threads=threads,
    )
    taken = n_steps * n_bodies if scheme.adaptive else out.results["n_steps"].sum()
    return taken / out.kernel_seconds, out


def option_settings(texts: Iterable[str]) -> dict[str, Any]:
    """The options of ``bench --option NAME=VALUE`` (each value read as YAML reads it in a
    config: ``1``, ``true``, ``-0.1``, ``'123'``) as a dict; a text without ``=`` raises
    `RbstudyError` in one line."""
    options = {}
    for text in texts:
        name, equals, value = text.partition("=")
        if not equals or not name.strip():
            raise RbstudyError(f"--option: expected NAME=VALUE such as compensated=1, got {text!r}")
        options[name.strip()] = parse_yaml(value, f"--option {name.strip()}")
    return options


def scheme_options(
    chosen: Sequence[Scheme], options: Mapping[str, Any]
) -> list[tuple[Scheme, dict[str, Any]]]:
    """Each scheme of ``chosen`` with the ``options`` (name -> value) it offers, validated
    (`rbstudy.schemes.Scheme.option_row`), as (scheme, its options) pairs; an option that no
    chosen scheme offers raises `SchemeError` naming the options they have."""
    offered = {option.name for scheme in chosen for option in scheme.options}
    for name in options:
        if name not in offered:
            raise SchemeError(
                f"no scheme measured has an option {name!r}",
                f"their options: {', '.join(sorted(offered)) or 'none'}",
                key="--option",
            )
    pairs = []
    for scheme in chosen:
        own = {name: value for name, value in options.items() if name in {o.name for o in scheme.options}}
        scheme.option_row(own)  # a bad value fails before anything runs
        pairs.append((scheme, own))
    return pairs


def _label(scheme: Scheme, options: Mapping[str, Any]) -> str:
    """A row's name: the scheme's, marked ``*`` when it runs with options (a footnote under
    the table names them: the rows keep to 100 columns)."""
    return f"{scheme.name}*" if options else scheme.name


class _Sizes(NamedTuple):
    """What a row measures: the ``batch_sizes``, the ``body_steps`` of a figure, the ``cores``
    of the second column, and how many runs a figure is the best of (``repeat``)."""

    batch_sizes: Sequence[int]
    body_steps: int
    cores: int
    repeat: int


def run_bench(
    schemes: Iterable[str] | None = None,
    batch_sizes: Sequence[int] = BATCH_SIZES,
    body_steps: int = BODY_STEPS,
    progress: bool = True,
    options: Mapping[str, Any] | None = None,
    repeat: int = 1,
) -> list[dict[str, Any]]:
    """Measure the figures and print them as a table on stdout, each scheme's compilation
    and measurements shown meanwhile (`rbstudy.pipeline.progress.Progress`) unless
    ``progress`` is False; returns them as a list of dicts. Each figure is the best of
    ``repeat`` rounds. ``options`` (name -> value) go to
    each scheme that offers them (`scheme_options`), whose rows a footnote marks."""
    chosen = scheme_options([get_scheme(name) for name in schemes or SCHEMES], options or {})
    scene = abaqus_top_scene()
    cores = default_threads()
    rows = []
    with Progress("bench", counted(len(chosen), "scheme"), quiet=not progress) as shown:
        # two lines, each within 100 columns for any --body-steps and number of cores
        shown.echo(
            f"rbstudy bench: Abaqus top, dt = {BENCH_DT:g} s, ~{body_steps:.0e} body-steps per figure,"
            + (f" the best of {repeat} rounds," if repeat > 1 else "")
        )
        shown.echo(
            f"  at least one step per body (dop853: {REFERENCE_STEPS} steps), {counted(cores, 'core')}"
            "; rates in body-steps/s of B bodies"
        )
        width = max(10, *(len(_label(*pair)) for pair in chosen))  # a plug-in's may be long
        # two header lines, so that six rates keep to 100 columns
        shown.echo(
            f"{'':{width}s} {'compile':>9s}"
            + "".join(f" {f'B={size}':>{_RATE}s}" * 2 for size in batch_sizes)
        )
        shown.echo(
            f"{'scheme':{width}s} {'s':>9s}"
            + f" {'1 core':>{_RATE}s} {counted(cores, 'core'):>{_RATE}s}" * len(batch_sizes)
        )
        sizes = _Sizes(batch_sizes, body_steps, cores, repeat)
        rows = [_compiled(scheme, own, shown) for scheme, own in chosen]
        # round after round of the whole table, not one figure's runs in a row: a busy spell
        # of the machine then slows a few runs of each figure, not every run of some
        for round_ in range(repeat):
            for (scheme, own), row in zip(chosen, rows, strict=True):
                _measure(scheme, own, scene, sizes, row, shown)
                if round_ == repeat - 1:
                    shown.echo(_line(row, sizes, width))
        if options:
            settings = ", ".join(f"{name}={value}" for name, value in options.items())
            shown.echo(f"* with {settings}; the others have no such option")
    return rows


def _compiled(scheme: Scheme, options: dict[str, Any], progress: Progress) -> dict[str, Any]:
    """A scheme's row, its kernels compiled (or loaded from the cache) and their time taken:
    the compile column counts the scheme's plain kernels; options that pick kernels of their
    own (``compensated``) compile them before the first figure's clock starts
    (`rbstudy.numerics.entry.CachedEntry.prepare`), so no rate counts a compilation."""
    progress.phase(f"bench: compiling {_label(scheme, options)}")
    start = time.perf_counter()
    scheme.ensure_compiled()
    return {
        "scheme": scheme.name,
        "options": options,
        "compile_seconds": time.perf_counter() - start,
        "label": _label(scheme, options),
    }


def _measure(
    scheme: Scheme,
    options: dict[str, Any],
    scene: Scene,
    sizes: _Sizes,
    row: dict[str, Any],
    progress: Progress,
) -> None:
    """One run of each of a scheme's figures with its ``options``, each kept in ``row`` where
    it is the best so far (`_compiled`'s row)."""
    name = row["label"]
    measured = sizes.batch_sizes[:1] if scheme.adaptive else sizes.batch_sizes
    progress.phase(f"bench: measuring {name}", 2 * len(measured), "figures")
    for size in measured:
        steps = REFERENCE_STEPS if scheme.adaptive else max(1, sizes.body_steps // size)
        for threads in (1, sizes.cores):
            progress.update(f"bench: {name}, B={size} on {counted(threads, 'thread')}")
            key = f"B{size}_threads{threads}"
            row[key] = max(row.get(key, 0.0), _rate(scheme, scene, size, steps, threads, options)[0])
            progress.advance()


def _line(row: dict[str, Any], sizes: _Sizes, width: int) -> str:
    """A scheme's line of the table: its name, compile time and best rates (``-`` for the
    batch sizes an adaptive scheme is not measured at)."""
    line = f"{row['label']:{width}s} {row['compile_seconds']:9.2f}"
    for size in sizes.batch_sizes:
        for threads in (1, sizes.cores):
            rate = row.get(f"B{size}_threads{threads}")
            line += f" {'-':>{_RATE}s}" if rate is None else f" {rate:{_RATE}.3e}"
    return line
