"""``needle_scenario``: command-line scenarios of the ANCF needle model (ROS-free).

    needle_scenario static --tip-mass 0.08 --elements 10 --json out.json --plot out.png
    needle_scenario static --tip-mass 0 0.02 0.04 0.06 0.08 --plot fig7.png
    needle_scenario pitch --json pitch.json --plot fig8.png
    needle_scenario free_vibration --tip-mass 0.02 --rho-inf 0.95 --beta 0 --json release.json
    needle_scenario insertion --speed 0.006 --depth 0.09
"""
from __future__ import annotations

import argparse
import sys

from needle_common.output_files import check_output_file

from needle_sim_ros.model import StaticSolveFailed, StepFailed

from . import free_vibration, insertion, pitch, static

SCENARIOS = (static, pitch, free_vibration, insertion)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="needle_scenario", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    subparsers = parser.add_subparsers(dest="scenario", required=True)
    for scenario in SCENARIOS:
        scenario.add_parser(subparsers).set_defaults(run=scenario.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        for option in ("json", "plot"):  # before the run: a long run must not fail at its end
            if getattr(args, option) is not None:
                check_output_file(getattr(args, option), f"--{option}")
        return args.run(args)
    except (ValueError, OSError, StaticSolveFailed, StepFailed) as error:
        unsolved = isinstance(error, (StaticSolveFailed, StepFailed))  # e.g. --tip-mass 1e300: beyond the model
        print(f"needle_scenario {args.scenario}: error: "
              f"{'the model found no solution for these inputs: ' if unsolved else ''}{error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
