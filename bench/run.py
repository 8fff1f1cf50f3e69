"""Run every ``bench/bench_*.py`` (each in its own process) -> bench/results/latest.jsonl.

    python bench/run.py                 # all benchmarks
    python bench/run.py sitl router     # only files whose name contains a word

The previous results file is kept as ``previous.jsonl``. A benchmark that crashes
is reported and makes the run exit non-zero; a missed target does not.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    results = HERE / "results"
    results.mkdir(exist_ok=True)
    latest = results / "latest.jsonl"
    if latest.exists():
        latest.replace(results / "previous.jsonl")
    latest.touch()
    scripts = sorted(HERE.glob("bench_*.py"))
    if argv:
        scripts = [s for s in scripts if any(word in s.name for word in argv)]
    failed = []
    for script in scripts:
        print(f"\n=== {script.name} ===", flush=True)
        t0 = time.monotonic()
        rc = subprocess.run([sys.executable, str(script)], cwd=HERE.parent, check=False).returncode
        print(
            f"=== {script.name}: {'ok' if rc == 0 else f'FAILED ({rc})'} in {time.monotonic() - t0:.0f} s", flush=True
        )
        if rc != 0:
            failed.append(script.name)
    print(f"\nresults: {latest}")
    if failed:
        print(f"benchmarks that crashed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
