"""Command line: ``rbstudy sweep | validate | schemes | bench``.

``sweep`` runs each study config's case and writes ``OUT/<study>/<study>.nc``; in this version
a study is one case (the sweep block, plots and reports arrive with issues 3 and 4).

Expected failures (`RbstudyError`) print one line and exit 2; bugs print a traceback.
"""

import argparse
import sys

from rbstudy.errors import RbstudyError

__all__ = ["main"]


def _schemes(args):
    from rbstudy.schemes import SCHEMES
    print(f"{'scheme':10s} {'order':>5s} {'kind':9s} {'keeps':16s} {'loads':5s} options / summary")
    for name, scheme in SCHEMES.items():
        kind = "adaptive" if scheme.adaptive else "implicit" if scheme.implicit else "explicit"
        keeps = ", ".join(scheme.keeps) or "-"
        options = ", ".join(f"{o.name}={o.default}" for o in scheme.options)
        print(f"{name:10s} {scheme.order:5d} {kind:9s} {keeps:16s} "
              f"{'yes' if scheme.handles_loads else 'no':5s} {scheme.summary}"
              + (f" [{options}]" if options else ""))
    return 0


def _bench(args):
    from rbstudy.bench import run_bench
    run_bench(schemes=args.schemes or None)
    return 0


def _validate(args):
    from rbstudy.config import load_study
    failures = 0
    for path in args.files:
        try:
            study = load_study(path)
        except RbstudyError as error:
            print(f"rbstudy: error: {error}", file=sys.stderr)
            failures += 1
            continue
        print(f"{path}: ok ({study.name}: {study.scheme}, dt = {study.dt:g} s)")
    return 2 if failures else 0


def _sweep(args):
    import pathlib

    from rbstudy.analytic import reference_solution
    from rbstudy.config import load_study
    from rbstudy.simulate import simulate
    from rbstudy.store import case_dataset, write_atomic
    studies = [load_study(path) for path in args.files]  # all configs checked before any run
    for study in studies:
        run = simulate([study.scene], study.scheme, study.dt, study.output_interval,
                       study.options)
        reference = reference_solution(study.scene, run.time, study.output_interval)
        dataset = case_dataset(study, run, reference)
        target = pathlib.Path(args.out) / study.name / f"{study.name}.nc"
        write_atomic(dataset, target)
        print(f"{study.name}: {study.scheme} dt = {study.dt:g} s, {run.n_steps[0]} steps, "
              f"{run.iterations[0]} Newton iterations, status {run.status_names[0]}")
        print(f"  final orientation error {float(dataset.final_orientation_error):.3e} rad "
              f"(reference: {reference.name})")
        if "precession_frequency" in dataset:
            print(f"  precession frequency {float(dataset.precession_frequency):.4f} rad/s, "
                  f"exact {float(dataset.precession_frequency_exact):.4f}")
        print(f"  wrote {target}")
    return 0


def build_parser():
    parser = argparse.ArgumentParser(
        prog="rbstudy", description="Parameter studies of rigid-body rotation integrators.")
    commands = parser.add_subparsers(dest="command", required=True)
    sweep = commands.add_parser("sweep", help="run study configs and archive the results")
    sweep.add_argument("files", nargs="+", metavar="FILE", help="study YAML files")
    sweep.add_argument("--out", default="results", help="results root (default: results/)")
    sweep.set_defaults(run=_sweep)
    validate = commands.add_parser("validate", help="check study configs without running")
    validate.add_argument("files", nargs="+", metavar="FILE", help="study YAML files")
    validate.set_defaults(run=_validate)
    schemes = commands.add_parser("schemes", help="list the registered schemes")
    schemes.set_defaults(run=_schemes)
    bench = commands.add_parser("bench", help="print body-steps per second per scheme")
    bench.add_argument("schemes", nargs="*", help="schemes to measure (default: all)")
    bench.set_defaults(run=_bench)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except RbstudyError as error:
        print(f"rbstudy: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
