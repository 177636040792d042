#!/usr/bin/env bash
# Set up everything (idempotent) and run the whole test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/setup_env.sh
printf '\033[1m[test]\033[0m running the test suite (package tests and suite-level tests)\n'
exec pytest needle_sim_ros/test needle_vision/test test "$@"
