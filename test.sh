#!/usr/bin/env bash
# Set up everything (idempotent) and run the whole test suite against requirements.lock, then the noble subset
# against requirements-noble.lock (Ubuntu 24.04's numpy 1.26, scipy 1.11, opencv 4.6, numba 0.59; .venv-noble,
# install-noble/). NEEDLE_NOBLE=0 skips the noble run. Extra arguments go to pytest (both runs).
set -euo pipefail
cd "$(dirname "$0")"
# The noble run: the package tests (numpy/scipy/opencv/numba cores, the nodes and the offline tools) and the
# installed executables; the suite-level live-node tests run once, in the main environment.
NOBLE_TESTS=(needle_sim_ros/test needle_vision/test test/test_installed.py test/test_packaging.py)

# Each run sources its environment in a child shell, so the two never mix.
run() {  # run <lock: "" or noble> <title> <pytest args...>
  local lock=$1 title=$2; shift 2
  NEEDLE_LOCK=$lock bash -c 'source scripts/setup_env.sh && printf "\033[1m[test]\033[0m %s\n" "$0" && exec pytest "$@"' \
    "$title" "$@"
}
status=0
run "" "running the test suite (package tests and suite-level tests)" \
  needle_sim_ros/test needle_vision/test test "$@" || status=$?
if [ "${NEEDLE_NOBLE:-1}" != 0 ]; then
  run noble "running the package tests and installed-executable tests on noble's versions (requirements-noble.lock)" \
    "${NOBLE_TESTS[@]}" "$@" || status=$((status ? status : $?))
fi
exit "$status"
