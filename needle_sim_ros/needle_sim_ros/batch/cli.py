"""``needle_batch``: the offline pipeline over many bags on Dask distributed (local processes by default).

    needle_batch sweep --bags bags/ --grid config/batch/sweep_example.yaml --output-dir out/sweep
    needle_batch identify --bags 'lab/*.mcap' --experiment lab.yaml \\
        --fit tissue.layers.tip_stiffness[0]=9e3 --fit tissue.layers.friction_coulomb[0]=5
    needle_batch sweep ... --scheduler tcp://host:8786      # an existing cluster (e.g. dask-jobqueue SLURM)

sweep writes OUT/results.parquet, OUT/results.csv (one row per bag and parameter set) and OUT/plots/; identify writes
OUT/identification.json, OUT/fit_history.csv and OUT/identified_params.yaml (a params file for the simulator).
Exit status: 0 done, 1 some task or the fit failed, 2 bad arguments or input.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from needle_common.cli_types import command_status, positive, positive_int
from needle_common.output_files import check_output_dir

from needle_sim_ros.batch.bags import BagEntry, BagListError, resolve_bags
from needle_sim_ros.batch.grid import GridError, load_grid

PIP_LINE = 'pip install "dask[distributed]" pandas pyarrow'


def _common(parser: argparse.ArgumentParser, default_output: str) -> None:
    parser.add_argument("--bags", required=True, help="a folder of bags, a glob (quoted) or a manifest file")
    parser.add_argument("--experiment", type=Path, help="experiment params file for every bag (default: "
                        "config/experiments/<bag name>.yaml, or the manifest's second column)")
    parser.add_argument("--output-dir", type=Path, default=Path(default_output), help=f"default: {default_output}")
    parser.add_argument("--duration", type=positive, help="process only the first S seconds of each bag")
    parser.add_argument("--workers", type=positive_int, help="local worker processes (default: the machine's cores)")
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler (e.g. tcp://host:8786)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def parser() -> argparse.ArgumentParser:
    main = argparse.ArgumentParser(prog="needle_batch", description=__doc__.split("\n\n")[0],
                                   formatter_class=argparse.RawDescriptionHelpFormatter,
                                   epilog=__doc__.split("\n\n", 1)[1])
    commands = main.add_subparsers(dest="command", required=True)
    sweep = commands.add_parser("sweep", help="every bag x every parameter set of a grid file")
    _common(sweep, "out/batch")
    sweep.add_argument("--grid", type=Path, required=True, help="grid file (YAML with sweep: and/or points:)")
    sweep.add_argument("--resume", action="store_true", help="skip tasks with a finished row in OUT (same bag "
                       "content and parameter set)")
    sweep.add_argument("--no-plots", action="store_true", help="do not write plots")
    fit = commands.add_parser("identify", help="fit tissue parameters to all bags")
    _common(fit, "out/identify")
    fit.add_argument("--fit", action="append", required=True, metavar="[NODE:]PARAM=INITIAL",
                     help="a parameter to fit (positive), e.g. tissue.layers.tip_stiffness[0]=9e3 (repeatable)")
    fit.add_argument("--shape-scale", type=positive, default=1e-4, help="shape residual scale [m] (default 1e-4)")
    fit.add_argument("--force-scale", type=positive, default=1e-2, help="force residual scale [N] (default 1e-2)")
    fit.add_argument("--moment-scale", type=positive, default=1e-3, help="moment residual scale [N m] (default 1e-3)")
    fit.add_argument("--step", type=positive, default=0.01, help="relative finite-difference step (default 0.01)")
    fit.add_argument("--max-evaluations", type=positive_int, default=30, help="optimiser evaluations (default 30)")
    return main


def run_sweep_command(args: argparse.Namespace, client, entries) -> int:
    from needle_sim_ros.batch.plots import write_sweep_plots
    from needle_sim_ros.batch.sweep import plan, run_sweep
    grid = load_grid(args.grid)
    tasks = plan(client, entries, grid.parameter_sets, args.experiment, args.duration)
    result = run_sweep(client, tasks, grid, args.output_dir, args.resume, args.quiet)
    failed = result.table[result.table["status"] != "ok"]
    print(f"[needle_batch] {len(result.table)} row(s): ran {result.ran}, reused {result.reused}, failed {len(failed)}")
    for row in failed.itertuples():
        print(f"[needle_batch] failed: {row.bag} (parameter set {row.parameter_set}): {row.error}", file=sys.stderr)
    no_reference = int((result.table["status"].eq("ok") & result.table["wrench_force_rms_n"].isna()).sum())
    if no_reference:
        print(f"[needle_batch] note: wrench error empty in {no_reference} row(s): the bag has no reference wrench "
              f"(/ground_truth/wrench)", file=sys.stderr)
    print(f"[needle_batch] table: {args.output_dir / 'results.parquet'}, {args.output_dir / 'results.csv'}")
    if not args.no_plots:
        files, notes = write_sweep_plots(result.table, grid.columns, args.output_dir / "plots")
        for note in notes:
            print(f"[needle_batch] note: {note}", file=sys.stderr)
        print(f"[needle_batch] plots: {len(files)} in {args.output_dir / 'plots'}")
    return 1 if len(failed) else 0


def run_identify_command(args: argparse.Namespace, client, entries) -> int:
    from needle_sim_ros.batch.identify import IdentifyError, identify
    from needle_sim_ros.batch.report import write_identification
    from needle_sim_ros.batch.sweep import plan
    from needle_sim_ros.batch.task import ResidualScales
    fits = args.fits
    bags = plan(client, entries, [{}], args.experiment, args.duration)
    try:
        result = identify(client, bags, fits, ResidualScales(args.shape_scale, args.force_scale, args.moment_scale),
                          args.step, args.max_evaluations, args.quiet)
    except IdentifyError as error:
        print(f"needle_batch: error: {error}", file=sys.stderr)
        return 1
    for bag, message in result.dropped.items():
        print(f"[needle_batch] dropped bag {bag}: {message}", file=sys.stderr)
    reference = next(b for b in bags if b.bag == result.bags[0])
    files = write_identification(args.output_dir, fits, result, reference)
    for fit, value, std in zip(fits, result.estimate, result.std):
        print(f"[needle_batch] {fit.label} = {value:.6g} +- {std:.2g} (initial {fit.initial:.6g})")
    print(f"[needle_batch] {result.evaluations} evaluation(s) over {len(result.bags)} bag(s): {result.message}")
    for name, path in files.items():
        print(f"[needle_batch] {name}: {path}")
    return 0 if result.success else 1


def checked_inputs(args: argparse.Namespace) -> list[BagEntry]:
    """The bag entries, after everything a run needs was checked before a cluster starts: the bags, the grid or
    the fitted parameters, every bag's experiment file, the output folder (made if missing). BagListError or
    GridError otherwise."""
    entries = resolve_bags(args.bags)
    if args.command == "sweep":
        load_grid(args.grid)  # bad grid files and fitted parameters fail before a cluster starts
    else:
        from needle_sim_ros.batch.identify import parse_fit
        args.fits = [parse_fit(text) for text in args.fit]
    if args.experiment is not None and not args.experiment.is_file():
        raise BagListError(f"--experiment '{args.experiment}': no such file")
    from needle_sim_ros.batch.sweep import experiment_path
    experiments = [(e.path, experiment_path(e, args.experiment)) for e in entries if Path(e.path).exists()]
    missing = [(bag, path) for bag, path in experiments if not Path(path).is_file()]
    if missing:  # a configuration error, not a bag's (a missing bag is a failed row: batch.bags)
        (bag, path), others = missing[0], len(missing) - 1
        raise BagListError(f"bag '{bag}': no experiment file '{path}'" + (f" (and {others} other bag(s))" if others
                           else "") + "; give one with --experiment FILE or in a manifest's second column")
    try:  # before a cluster starts and the tasks run (made if missing)
        check_output_dir(args.output_dir, "--output-dir")
    except ValueError as error:
        raise BagListError(str(error)) from error
    return entries


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        import dask  # noqa: F401
        import distributed  # noqa: F401
        import pandas  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError as error:
        print(f"needle_batch: error: {error.name} is not installed; needle_batch needs: {PIP_LINE}", file=sys.stderr)
        return 2
    return command_status("needle_batch", run, args, (BagListError, GridError), (OSError,))


def run(args: argparse.Namespace) -> int:
    """The checked inputs' sweep or identification on a cluster."""
    from needle_sim_ros.batch.cluster import open_client
    entries = checked_inputs(args)
    with open_client(args.workers, args.scheduler) as client:
        command = run_sweep_command if args.command == "sweep" else run_identify_command
        return command(args, client, entries)


if __name__ == "__main__":
    sys.exit(main())
