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

# e2e: one pytest process per file. rospy binds a process to one master for life
# (init_node can run once), and e2e modules start their own roscore each.
run_e2e() {
  local start=$SECONDS rc=0 f name
  printf '\033[1m[test] tier e2e (one process per file)\033[0m\n'
  while IFS= read -r f; do
    name="$(basename "$(dirname "$f")")_$(basename "$f" .py)"
    scripts/in_env python -m pytest "$f" -p no:cacheprovider --timeout=600 \
      --junitxml="artifacts/junit-e2e-$name.xml" "$@"
    local frc=$?
    [ $frc -eq 5 ] && frc=0
    [ $frc -ne 0 ] && { rc=1; printf '\033[1;31m[test] e2e %s FAILED\033[0m\n' "$f"; }
  done < <(find tests/e2e -name 'test_*.py' | sort)
  printf '\033[1m[test] tier e2e: %s in %ss\033[0m\n' "$([ $rc -eq 0 ] && echo passed || echo FAILED)" "$((SECONDS - start))"
  return $rc
}

# The unit tier measures branch coverage (pyproject.toml [tool.coverage]) and prints the total; the
# per-file table goes to artifacts/coverage-unit.txt and the XML report to artifacts/coverage-unit.xml.
run_unit() {
  run_tier unit 120 --cov --cov-report= "$@"
  local rc=$?
  if [ -f artifacts/.coverage ]; then
    scripts/in_env python -m coverage report > artifacts/coverage-unit.txt 2>&1
    scripts/in_env python -m coverage xml -q -o artifacts/coverage-unit.xml > /dev/null 2>&1
    printf '\033[1m[test] tier unit: branch coverage %s %% (per file: artifacts/coverage-unit.txt)\033[0m\n' \
      "$(scripts/in_env python -m coverage report --format=total 2>/dev/null || echo '?')"
  fi
  return $rc
}

rc=0
case "$tier" in
  unit) run_unit "$@" || rc=1 ;;
  ros) run_tier ros 300 "$@" || rc=1 ;;
  e2e) run_e2e "$@" || rc=1 ;;
  all)
    run_unit "$@" || rc=1
    run_tier ros 300 "$@" || rc=1
    run_e2e "$@" || rc=1
    ;;
  *) echo "unknown tier '$tier' (unit, ros, e2e or all)" >&2; exit 2 ;;
esac
exit $rc
