#!/usr/bin/env bash
# Idempotent setup for a fresh Debian 12 machine: apt packages, the .venv, the
# editable ROS-free packages, then catkin_make. Each slow step is skipped when a
# stamp in .stamps/ says its inputs have not changed since it last succeeded.
#
#   scripts/setup.sh            # everything
#   scripts/setup.sh apt|venv|compile|build
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
STAMPS="$REPO/.stamps"
VENV="$REPO/.venv"
SYS_PY=/usr/bin/python3
mkdir -p "$STAMPS"

say() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }
warn() { printf '\033[1;33m[setup] warning:\033[0m %s\n' "$*" >&2; }
die() { printf '\033[1;31m[setup] error:\033[0m %s\n' "$*" >&2; exit 1; }

hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }

check_os() {
  [ -r /etc/os-release ] || die "cannot read /etc/os-release; this project supports Debian 12 (bookworm) only. Use docker/Dockerfile on other systems."
  # shellcheck disable=SC1091
  . /etc/os-release
  if [ "${ID:-}" != "debian" ] || [ "${VERSION_ID:-}" != "12" ]; then
    die "this is ${PRETTY_NAME:-an unknown OS}; the project needs Debian 12 (bookworm), whose archive ships ROS 1 as Debian packages. Use docker/Dockerfile (debian:bookworm) on other systems."
  fi
}

apt_packages() { grep -v '^[[:space:]]*#' "$REPO/apt-packages.txt" | grep -v '^[[:space:]]*$'; }

step_apt() {
  local want stamp missing=()
  want="$(hash_of "$REPO/apt-packages.txt")"
  stamp="$STAMPS/apt"
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    say "apt: packages already installed (stamp up to date)"
    return
  fi
  while read -r pkg; do
    if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
      missing+=("$pkg")
    fi
  done < <(apt_packages)
  if [ ${#missing[@]} -gt 0 ]; then
    command -v apt-get >/dev/null || die "apt-get is not available; install these Debian packages by hand: ${missing[*]}"
    local sudo=""
    if [ "$(id -u)" -ne 0 ]; then
      command -v sudo >/dev/null || die "need root to install ${#missing[@]} Debian packages (${missing[*]}); run as root or install sudo"
      sudo="sudo"
    fi
    say "apt: installing ${#missing[@]} packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    $sudo apt-get update -qq || die "apt-get update failed; check the network or /etc/apt/sources.list.d"
    $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null \
      || die "apt-get install failed for: ${missing[*]}"
  else
    say "apt: all $(apt_packages | wc -l) packages present"
  fi
  echo "$want" > "$stamp"
}

step_venv() {
  local want stamp
  want="$(hash_of "$REPO/requirements.txt" "$REPO/requirements-nodeps.txt" \
    "$REPO"/uav_common/pyproject.toml "$REPO"/sitl/pyproject.toml "$REPO"/mavlink_router/pyproject.toml)"
  stamp="$STAMPS/venv"
  if [ -x "$VENV/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    say "venv: .venv up to date"
    return
  fi
  [ -x "$SYS_PY" ] || die "$SYS_PY not found; install python3 (apt step) first"
  if [ ! -x "$VENV/bin/python" ]; then
    say "venv: creating .venv from $SYS_PY (--system-site-packages, so rospy is visible)"
    "$SYS_PY" -m venv --system-site-packages "$VENV"
  fi
  local pip=("$VENV/bin/python" -m pip --disable-pip-version-check -q)
  say "venv: installing pinned requirements"
  "${pip[@]}" install -r "$REPO/requirements.txt"
  "${pip[@]}" install --no-deps -r "$REPO/requirements-nodeps.txt"
  say "venv: installing uav_common, sitl and mavlink_router (editable)"
  local pkgs=()
  for p in uav_common sitl mavlink_router; do
    [ -f "$REPO/$p/pyproject.toml" ] && pkgs+=(-e "$REPO/$p")
  done
  "${pip[@]}" install --no-deps --no-build-isolation "${pkgs[@]}"
  "$VENV/bin/python" - <<'EOF' || die "the venv is broken (see above); delete .venv and run make setup again"
import numpy, cv2, rospy, pymavlink, jsbsim, mavsdk, moderngl
assert numpy.__version__.startswith("1."), f"numpy {numpy.__version__} >= 2 breaks Debian's compiled modules"
EOF
  echo "$want" > "$stamp"
}

step_compile() {
  [ -x "$VENV/bin/python" ] || die "no .venv; run the venv step first"
  # mypyc compiles the SITL's per-step modules into sitl/build/compiled-core (skipped while its stamp matches
  # the sources; the SITL runs the pure-Python modules whenever it does not, see docs/sitl.md "Speed").
  mkdir -p "$REPO/sitl/build"
  (
    flock 9
    "$VENV/bin/python" "$REPO/scripts/build_sitl_core.py"
  ) 9>"$REPO/sitl/build/compile.lock" \
    || warn "compiling the SITL's per-step modules failed (log: sitl/build/compiled-core.log); the SITL runs" \
      "its pure-Python modules, correct but about 1.5x slower (docs/sitl.md \"Speed\")"
}

step_build() {
  [ -f /usr/bin/catkin_make ] || die "catkin_make not found; run the apt step first"
  say "build: catkin_make (Release, /usr/bin/python3)"
  # New .msg/.srv files and packages need a CMake re-run; detect them by name.
  local layout force=() stamp="$STAMPS/catkin_layout"
  layout="$(cd "$REPO/catkin_ws/src" && find . -name package.xml -o -name '*.msg' -o -name '*.srv' -o -name 'CMakeLists.txt' | sort | sha256sum | cut -c1-16)"
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$layout" ]; then force=(--force-cmake); fi
  # Serialise concurrent builds of the same workspace (parallel shells, helpers).
  (
    flock 9
    cd "$REPO/catkin_ws"
    # `install` builds and then installs into catkin_ws/install, the layout a companion computer runs
    # (source catkin_ws/install/setup.bash); the devel space is what the checkout uses.
    PATH="/usr/bin:$PATH" catkin_make "${force[@]}" -DPYTHON_EXECUTABLE=/usr/bin/python3 \
      -DCMAKE_BUILD_TYPE=Release -DCATKIN_ENABLE_TESTING=OFF -j"$(nproc)" install > "$STAMPS/catkin_make.log" 2>&1 \
      || { tail -n 60 "$STAMPS/catkin_make.log" >&2; die "catkin_make failed; full log in .stamps/catkin_make.log"; }
  ) 9>"$STAMPS/catkin.lock"
  echo "$layout" > "$stamp"
  say "build: ok (source catkin_ws/devel/setup.bash to use the workspace; catkin_ws/install is the install space)"
}

main() {
  check_os
  case "${1:-all}" in
    apt) step_apt ;;
    venv) step_venv ;;
    compile) step_compile ;;
    build) step_build ;;
    all) step_apt; step_venv; step_compile; step_build ;;
    *) die "unknown step '$1' (use apt, venv, compile, build or all)" ;;
  esac
}

main "$@"
