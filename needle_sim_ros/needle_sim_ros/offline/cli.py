"""``needle_offline``: the whole pipeline (simulator + stereo + comparison) over a bag, as fast as possible.

    needle_offline bags/dynamic_pitch.mcap            # parameters: <share>/config/experiments/dynamic_pitch.yaml
    needle_offline BAG --duration 2.6 --set needle_simulator:needle.youngs_modulus=250e9 --output-dir out/wrong_e

Writes into the output directory (default ``out/<bag>/offline``): ``pipeline.mcap`` (what ``needle_compare`` records
live; the same bytes for the same input), ``summary.json`` (RMSE statistics, counts, the simulator's effort, wall
time, real-time factor and, for synthetic bags, model and measurement against the ground truth) and, with
``--plots``, ``plots/`` (matplotlib adds ~1 s per run). Exit status: 0 done, 1 the run failed, 2 bad arguments,
parameters or input.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml
from tqdm import tqdm

from needle_common.cli_types import command_status, non_negative, positive

from needle_sim_ros.parameters.experiment import NODES, ExperimentConfigError, experiment_for_bag, load_experiment
from needle_sim_ros.offline.pipeline import OfflinePipeline
from needle_sim_ros.offline.plots import write_plots
from needle_sim_ros.offline.results import versus_ground_truth
from needle_common.bag_reader import BagReader, BagReadError
from needle_sim_ros.recording import RecordingError


def parse_override(text: str) -> tuple[str, str, Any]:
    """``node:name=value`` -> (node, name, value parsed as YAML)."""
    node, sep, rest = text.partition(":")
    name, equals, value = rest.partition("=")
    if not (sep and equals and node in NODES and name):
        raise argparse.ArgumentTypeError(f"'{text}': expected NODE:PARAMETER=VALUE with NODE one of {', '.join(NODES)}")
    return node, name, yaml.safe_load(value)


def summary_lines(summary: dict[str, Any]) -> list[str]:
    """Human-readable lines of a run summary (offline or live)."""
    c = summary["comparison"]
    mm = (lambda v: f"{v * 1e3:.3f} mm" if v is not None else "n/a")
    lines = [f"compared {c['compared']} measurement(s), unpaired {c['unpaired_measurements']}, "
             f"rejected {sum(c['rejected_inputs'].values())}",
             f"RMSE mean {mm(c['rmse_mean_m'])}, max {mm(c['rmse_max_m'])}; tip error mean "
             f"{mm(c['tip_error_mean_m'])}; largest sample error {mm(c['max_error_m'])}"]
    truth = summary.get("versus_ground_truth")
    if truth and truth["instants"]:
        lines.append(f"against the ground truth: model {mm(truth['model_rmse_mean_m'])}, measurement "
                     f"{mm(truth['measurement_rmse_mean_m'])} (RMS over {truth['instants']} instants)")
    if truth and truth.get("wrench_samples"):
        lines.append(f"wrench against the reference: force RMS {truth['wrench_force_rms_n']:.4f} N, max "
                     f"{truth['wrench_force_max_n']:.4f} N (reference RMS {truth['wrench_reference_rms_n']:.4f} N); "
                     f"torque RMS {truth['wrench_torque_rms_nm']:.5f} N m, max {truth['wrench_torque_max_nm']:.5f} N m "
                     f"({truth['wrench_samples']} samples)")
    timing = summary.get("timing")
    if timing and timing.get("real_time_factor"):
        lines.append(f"{timing['simulated_s']:.2f} s of bag in {timing['wall_s']:.2f} s wall: "
                     f"{timing['real_time_factor']:.2f}x real time")
    return lines


def publish(staging: Path, output_dir: Path) -> None:
    """Move a run's results into place: the old summary goes first and the new one comes last, so a summary.json
    always describes the pipeline.mcap and plots next to it; stale plots of an earlier run are removed."""
    (output_dir / "summary.json").unlink(missing_ok=True)
    os.replace(staging / "pipeline.mcap", output_dir / "pipeline.mcap")
    shutil.rmtree(output_dir / "plots", ignore_errors=True)
    if (staging / "plots").is_dir():
        os.replace(staging / "plots", output_dir / "plots")
    os.replace(staging / "summary.json", output_dir / "summary.json")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="needle_offline", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n",
                                                                                                                1)[1])
    parser.add_argument("bag", type=Path, help="rosbag2 MCAP recording (.mcap file or bag directory)")
    parser.add_argument("--experiment", type=Path, help="experiment params file (default: the installed "
                        "share/needle_sim_ros/config/experiments/<bag name>.yaml)")
    parser.add_argument("--output-dir", type=Path, help="output directory (default: out/<bag name>/offline)")
    parser.add_argument("--start-offset", type=non_negative, default=0.0, help="skip the first S seconds of the bag")
    parser.add_argument("--duration", type=positive, help="process only S seconds (default: to the end)")
    parser.add_argument("--set", dest="overrides", action="append", type=parse_override, default=[],
                        metavar="NODE:PARAM=VALUE", help="override a node parameter (repeatable)")
    parser.add_argument("--instants", type=float, nargs="+", help="centerline plot instants [s from the bag start]")
    parser.add_argument("--no-stereo", action="store_true", help="compare a recorded needle/measured_shape instead")
    parser.add_argument("--plots", action="store_true", help="also write plots/ (~1 s more)")
    parser.add_argument("--no-plots", dest="plots", action="store_false", help="no plots (the default since plots "
                        "became an option; accepted for the scripts that passed it)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--stop-on-corrupt", action="store_true", help="stop at a corrupt chunk or message of the "
                        "bag (default: skip it and count it in the summary)")
    return command_status("needle_offline", run, parser.parse_args(argv),
                          (BagReadError, ValueError), (RecordingError, OSError))


def run(args: argparse.Namespace) -> int:
    """Check the bag, the experiment and the output directory, then run into a staging directory and move the
    results into place only when the run succeeded."""
    overrides: dict[str, dict[str, Any]] = {}
    for node, name, value in args.overrides:
        overrides.setdefault(node, {})[name] = value
    output_dir = args.output_dir or Path("out") / args.bag.stem / "offline"
    reader = BagReader(args.bag, args.stop_on_corrupt)
    reader.check_start_offset(args.start_offset)
    try:
        experiment = load_experiment(args.experiment) if args.experiment else experiment_for_bag(args.bag)
        pipeline = OfflinePipeline(experiment, overrides, stereo=False if args.no_stereo else None)
    except ExperimentConfigError as error:
        hint = "" if args.experiment else " (give the bag's experiment file with --experiment FILE)"
        raise ExperimentConfigError(f"{error}{hint}") from error
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"output directory '{output_dir}': {error.strerror or error}") from error
    staging = Path(tempfile.mkdtemp(prefix=".needle_offline-", dir=output_dir))
    try:
        return run_and_publish(args, experiment, pipeline, reader, staging, output_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def run_and_publish(args: argparse.Namespace, experiment, pipeline: OfflinePipeline, reader: BagReader,
                    staging: Path, output_dir: Path) -> int:
    """Run into ``staging``; on success replace the results in ``output_dir`` (summary.json last)."""
    name = args.bag.stem
    total = (reader.end_time_ns - reader.start_time_ns) / 1e9 - args.start_offset
    total = min(total, args.duration) if args.duration is not None else total
    with tqdm(total=round(total, 3), unit="s", desc=f"needle_offline {name}", disable=args.quiet,
              bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} s of bag [{elapsed}<{remaining}]") as bar:
        def progress(done: float) -> None:
            bar.update(min(round(done, 3), bar.total) - bar.n)
        result = pipeline.run(reader, staging / "pipeline.mcap", args.start_offset, args.duration, progress)
    summary, log = result.summary, result.log
    for warning in summary["warnings"]:
        print(f"[needle_offline] note: {warning}", file=sys.stderr)
    summary["versus_ground_truth"] = versus_ground_truth(log)
    if args.plots:
        instants = args.instants or experiment.settings.plot_instants
        written = write_plots(log, staging / "plots", instants, name)
        summary["plots"] = [str(output_dir / "plots" / p.name) for p in written]
    summary["log"] = str(output_dir / "pipeline.mcap")
    (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    publish(staging, output_dir)
    for line in summary_lines(summary):
        print(f"[needle_offline] {line}")
    print(f"[needle_offline] MCAP log: {output_dir / 'pipeline.mcap'}\n"
          f"[needle_offline] summary: {output_dir / 'summary.json'}")
    if args.plots:
        print(f"[needle_offline] plots: {output_dir / 'plots'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
