#!/usr/bin/env bash
# Set up everything (idempotent) and run the whole test suite twice: against requirements.lock (.venv, install/),
# then against requirements-noble.lock — Ubuntu 24.04's numpy 1.26, scipy 1.11, opencv 4.6 and numba 0.59
# (.venv-noble, install-noble/). NEEDLE_NOBLE=0 skips the noble run. Extra arguments go to pytest (both runs).
set -euo pipefail
cd "$(dirname "$0")"
TESTS=(needle_common/test needle_sim_ros/test needle_vision/test test)

# Each run sources its environment in a child shell, so the two never mix.
run() {  # run <lock: "" or noble> <title> <pytest args...>
  local lock=$1 title=$2; shift 2
  df -h . "${TMPDIR:-/tmp}" | sed 's/^/[disk] /'  # a full disk fails tests far from its cause: say what was free
  NEEDLE_LOCK=$lock bash -c \
    'source scripts/setup_env.sh && printf "\033[1m[test]\033[0m %s\n" "$0" && exec pytest "$@"' "$title" "$@"
}
# Lint first (pycodestyle + pyflakes, lines <= 120: ruff.toml), in the main environment.
NEEDLE_LOCK="" bash -c 'source scripts/setup_env.sh >/dev/null && printf "\033[1m[test]\033[0m lint (ruff)\n" \
  && exec ruff check .'
status=0
run "" "running the test suite (package tests and suite-level tests)" "${TESTS[@]}" "$@" || status=$?
if [ "${NEEDLE_NOBLE:-1}" != 0 ]; then
  run noble "running the test suite on Ubuntu 24.04's versions (requirements-noble.lock)" "${TESTS[@]}" "$@" \
    || status=$((status ? status : $?))
fi
exit "$status"
