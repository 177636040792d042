#!/usr/bin/env bash
# Set up everything (idempotent) and run the main job. Extra arguments go to the main job.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/setup_env.sh
exec python scripts/main_job.py "$@"
