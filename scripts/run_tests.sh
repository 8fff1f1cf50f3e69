#!/usr/bin/env bash
# Run one test tier or all of them inside the project environment.
#   scripts/run_tests.sh unit|ros|e2e|all [extra pytest args]
# JUnit XML and artifacts (rendered images, logs) go to artifacts/.
set -uo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"
tier="${1:-all}"; shift || true
mkdir -p artifacts
export UAV_ARTIFACTS="$REPO/artifacts"
export ROS_LOG_DIR="$REPO/artifacts/ros_log"
export MESA_SHADER_CACHE_DIR="$REPO/artifacts/.mesa_cache"

run_tier() {
  local name="$1"; shift
  local timeout="$1"; shift
  local start=$SECONDS
  printf '\033[1m[test] tier %s\033[0m\n' "$name"
  scripts/in_env python -m pytest "tests/$name" -p no:cacheprovider --timeout="$timeout" \
    --junitxml="artifacts/junit-$name.xml" "$@"
  local rc=$?
  # pytest exits 5 when a tier has no tests yet; that is not a failure.
  [ $rc -eq 5 ] && rc=0
  printf '\033[1m[test] tier %s: %s in %ss\033[0m\n' "$name" "$([ $rc -eq 0 ] && echo passed || echo FAILED)" "$((SECONDS - start))"
  return $rc
}

rc=0
case "$tier" in
  unit) run_tier unit 120 "$@" || rc=1 ;;
  ros) run_tier ros 300 "$@" || rc=1 ;;
  e2e) run_tier e2e 600 "$@" || rc=1 ;;
  all)
    run_tier unit 120 "$@" || rc=1
    run_tier ros 300 "$@" || rc=1
    run_tier e2e 600 "$@" || rc=1
    ;;
  *) echo "unknown tier '$tier' (unit, ros, e2e or all)" >&2; exit 2 ;;
esac
exit $rc
