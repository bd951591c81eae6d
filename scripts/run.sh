#!/usr/bin/env bash
# Run a command in the project environment: scripts/run.sh byc doctor
set -euo pipefail
# shellcheck disable=SC1091
. "$(dirname "${BASH_SOURCE[0]}")/env.sh"
exec "$@"
