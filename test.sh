#!/usr/bin/env bash
# Set up everything (idempotent) and run the whole test suite twice: against requirements.lock (.venv, install/),
# then against requirements-noble.lock — Ubuntu 24.04's numpy 1.26, scipy 1.11, opencv 4.6 and numba 0.59
# (.venv-noble, install-noble/). NEEDLE_NOBLE=0 skips the noble run. Extra arguments go to pytest (both runs).
set -euo pipefail
cd "$(dirname "$0")"
TESTS=(needle_common/test needle_sim_ros/test needle_vision/test test)

elapsed() {  # where CI's 90 minutes went
  printf '\033[1m[time]\033[0m %s at %d min %02d s\n' "$1" $((SECONDS / 60)) $((SECONDS % 60))
}

# Each run sources its environment in a child shell, so the two never mix.
run() {  # run <lock: "" or noble> <title> <pytest args...>
  local lock=$1 title=$2; shift 2
  df -h . "${TMPDIR:-/tmp}" | sed 's/^/[disk] /'  # a full disk fails tests far from its cause: say what was free
  NEEDLE_LOCK=$lock bash -c \
    'source scripts/setup_env.sh && printf "\033[1m[test]\033[0m %s\n" "$0" && exec pytest "$@"' "$title" "$@"
}
# The noble environment is set up (pip, colcon build, its kernels compiled: single-threaded, 10-30 min) in the
# background, beside the main environment's set-up and test run: on CI's 2 cores the two runs in sequence would
# spend most of CI's 90 minutes; its output is shown when the noble run begins.
NOBLE=${NEEDLE_NOBLE:-1}
if [ "$NOBLE" != 0 ]; then
  noble_log=$(mktemp)
  NEEDLE_LOCK=noble setsid bash scripts/setup_env.sh > "$noble_log" 2>&1 &  # its own process group
  noble_setup=$!
  trap 'kill -- -"$noble_setup" 2>/dev/null || true' EXIT  # a failed main set-up or lint ends it, pip and colcon
fi
# The main environment, then lint (pycodestyle + pyflakes, lines <= 120: ruff.toml) in it.
NEEDLE_LOCK="" bash -c 'source scripts/setup_env.sh && printf "\033[1m[test]\033[0m lint (ruff)\n" && exec ruff check .'
elapsed "lint done"
status=0
run "" "running the test suite (package tests and suite-level tests)" "${TESTS[@]}" "$@" || status=$?
elapsed "main lock's run done"
if [ "$NOBLE" != 0 ]; then
  noble_status=0
  wait "$noble_setup" || noble_status=$?
  sed 's/^/[noble] /' "$noble_log" && rm -f "$noble_log"
  [ "$noble_status" = 0 ] || { echo "[noble] the noble environment's set-up failed (exit $noble_status)" >&2; exit 1; }
  run noble "running the test suite on Ubuntu 24.04's versions (requirements-noble.lock)" "${TESTS[@]}" "$@" \
    || status=$((status ? status : $?))
  elapsed "noble lock's run done"
fi
exit "$status"
