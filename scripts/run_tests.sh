#!/usr/bin/env bash
# Run pytest inside a private network namespace (only `lo`), so no test traffic, DDS included,
# can leave the machine. Falls back to loopback-only DDS settings where unshare is not allowed.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ -z "${BYC_NETNS:-}" ]; then
  if unshare -n true 2>/dev/null; then
    exec unshare -n env BYC_NETNS=private bash "$0" "$@"
  fi
  echo "run_tests: cannot create a network namespace here; DDS is limited to localhost instead" >&2
  export BYC_NETNS=shared
fi
[ "$BYC_NETNS" = private ] && ip link set lo up
# A fresh domain per run keeps concurrent runs (outside a namespace) from seeing each other.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 100) + 1 ))}"
# shellcheck disable=SC1091
. "$ROOT/scripts/env.sh"
cd "$ROOT"
exec python -m pytest "$@"
