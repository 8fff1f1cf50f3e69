#!/usr/bin/env python3
"""Compile the SITL's per-step modules with mypyc into sitl/build/compiled-core (make setup runs it).

Skips the build when the stamp there matches the sources (``sitl.compiled_core.sources_digest``).
Builds in a temporary directory and swaps the result in whole, so a running SITL or an
interrupted build never sees half a build. Exit 0 on success or when up to date, 1 on a failed
build (the compiler's output is in sitl/build/compiled-core.log).

    .venv/bin/python scripts/build_sitl_core.py [--force]
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ["SITL_PURE_PYTHON"] = "1"  # never load the build being replaced

from sitl import compiled_core

REPO = Path(__file__).resolve().parent.parent
SRC = REPO / "sitl" / "src"

SETUP_PY = """
import sys
from setuptools import setup
from mypyc.build import mypycify

files, build_lib, build_temp, target_dir, config = sys.argv[1].split(","), *sys.argv[2:6]
setup(
    name="sitl_compiled_core",
    ext_modules=mypycify(
        [f"--config-file={config}", *files], group_name="sitl_core", opt_level="3", target_dir=target_dir
    ),
    script_args=["build_ext", "--build-lib", build_lib, "--build-temp", build_temp],
)
"""


def main() -> int:
    force = "--force" in sys.argv[1:]
    out = compiled_core.BUILD_DIR
    digest = compiled_core.sources_digest()
    stamp = out / compiled_core.STAMP_NAME
    if not force and stamp.is_file() and stamp.read_text(encoding="utf-8").strip() == digest:
        print(f"[build_sitl_core] compiled core up to date ({out})")
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    log_path = out.parent / "compiled-core.log"
    files = ",".join(f"sitl/{m.replace('.', '/')}.py" for m in compiled_core.COMPILED_MODULES)
    with tempfile.TemporaryDirectory(prefix="sitl-core-", dir=out.parent) as tmp:
        tmp_path = Path(tmp)
        script = tmp_path / "setup_core.py"
        script.write_text(SETUP_PY, encoding="utf-8")
        lib = tmp_path / "lib"
        config = REPO / "pyproject.toml"  # the project's mypy settings (untyped third-party imports are Any)
        cmd = [sys.executable, str(script), files, str(lib), str(tmp_path / "temp"), str(tmp_path / "c"), str(config)]
        print(f"[build_sitl_core] mypyc: {len(compiled_core.COMPILED_MODULES)} modules of sitl (about a minute)")
        with log_path.open("w", encoding="utf-8") as log:
            result = subprocess.run(cmd, cwd=SRC, stdout=log, stderr=subprocess.STDOUT, check=False)
        if result.returncode != 0:
            print(f"[build_sitl_core] error: mypyc failed (exit {result.returncode}); see {log_path}", file=sys.stderr)
            return 1
        (lib / compiled_core.STAMP_NAME).write_text(digest + "\n", encoding="utf-8")
        old = out.parent / f"{out.name}.old"
        shutil.rmtree(old, ignore_errors=True)
        if out.exists():
            out.rename(old)
        lib.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    print(f"[build_sitl_core] compiled core built ({out})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
