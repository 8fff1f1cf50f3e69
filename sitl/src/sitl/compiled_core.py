"""The SITL's per-step modules compiled with mypyc, used only while they match the sources.

The autopilot's Python step costs several times the flight dynamics; compiling the modules
that run every physics step (:data:`COMPILED_MODULES`: the autopilot core and the telemetry
encoder, strictly typed already) with mypyc makes them two to three times faster and gives
the same numbers bit for bit (the same IEEE double operations in the same order;
``tests/unit/sitl/test_sitl_compiled_core.py`` flies scripted flights both ways and compares
the trajectory and every frame).

``make setup`` builds them (``scripts/build_sitl_core.py``) into :data:`BUILD_DIR`, outside
the source tree, with a stamp: the digest of every source they could depend on
(:func:`sources_digest`). :func:`activate` runs when :mod:`sitl` is imported, before any core
module: it puts the build in front of ``sitl.core.__path__`` only if the stamp matches the
sources of this checkout, so an edited SITL runs as edited (pure Python, with a warning that
says how to rebuild) and never as a stale build. ``SITL_PURE_PYTHON=1`` forces the pure-Python
core (a debugger, coverage, or a comparison).
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "BUILD_DIR",
    "COMPILED_MODULES",
    "PURE_ENV",
    "SHARED_LIB",
    "CoreChoice",
    "activate",
    "active",
    "choose",
    "source_files",
    "sources_digest",
]

log = logging.getLogger("sitl.compiled_core")

#: The modules (under ``sitl``) that run every step or every outer-loop step: mypyc compiles these.
COMPILED_MODULES = (
    "core.state",
    "core.control",
    "core.landing",
    "core.battery",
    "core.estimator",
    "core.failsafe",
    "core.navigator",
    "core.telemetry",
    "core.autopilot",
    "shell.encode",
)
#: The subpackages holding them (the build goes in front of their ``__path__``).
_SUBPACKAGES = ("core", "shell")
#: Set to 1 to run the pure-Python core even when a current build exists.
PURE_ENV = "SITL_PURE_PYTHON"
#: mypyc's shared library of the group (every compiled module imports it by this name).
SHARED_LIB = "sitl_core__mypyc"

_SITL_SRC = Path(__file__).resolve().parent  # .../sitl/src/sitl
#: Where ``scripts/build_sitl_core.py`` puts the build: ``sitl/build/compiled-core`` of the checkout.
BUILD_DIR = _SITL_SRC.parent.parent / "build" / "compiled-core"
STAMP_NAME = "sources.sha256"


def source_files() -> list[tuple[str, Path]]:
    """What a compiled module can depend on: every module of sitl, and uav_common's top-level modules."""
    files = [(p.relative_to(_SITL_SRC.parent).as_posix(), p) for p in sorted(_SITL_SRC.rglob("*.py"))]
    spec = importlib.util.find_spec("uav_common")
    if spec is not None and spec.origin is not None:
        common = Path(spec.origin).parent
        files += [(f"uav_common/{p.name}", p) for p in sorted(common.glob("*.py"))]
    return files


def sources_digest() -> str:
    """SHA-256 over the names and contents of :func:`source_files`, the modules list and the Python ABI."""
    h = hashlib.sha256()
    h.update(f"{sys.implementation.cache_tag} {' '.join(COMPILED_MODULES)}\n".encode())
    for label, path in source_files():
        h.update(f"{label}\n".encode())
        h.update(path.read_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class CoreChoice:
    """Which core runs, and why."""

    compiled: bool
    reason: str


def choose(build_dir: Path, digest: str, environ: dict[str, str] | os._Environ[str]) -> CoreChoice:
    """Use the build in ``build_dir`` only if it is complete and stamped with ``digest``."""
    if environ.get(PURE_ENV, "") not in ("", "0"):
        return CoreChoice(compiled=False, reason=f"pure Python ({PURE_ENV} is set)")
    stamp = build_dir / STAMP_NAME
    if not stamp.is_file():
        return CoreChoice(compiled=False, reason=f"pure Python (no compiled core in {build_dir}; make setup builds it)")
    if stamp.read_text(encoding="utf-8").strip() != digest:
        return CoreChoice(
            compiled=False,
            reason=f"pure Python (the compiled core in {build_dir} is older than the sources; "
            "run `make setup` or `scripts/setup.sh compile` to rebuild it)",
        )
    missing = [m for m in COMPILED_MODULES if not list((build_dir / "sitl").glob(f"{m.replace('.', '/')}.*.so"))]
    if missing or not list(build_dir.glob(f"{SHARED_LIB}.*.so")):
        return CoreChoice(
            compiled=False, reason=f"pure Python (the compiled core in {build_dir} is incomplete: {missing})"
        )
    return CoreChoice(compiled=True, reason=f"compiled with mypyc ({build_dir})")


_ACTIVE: CoreChoice | None = None


def active() -> CoreChoice:
    """The choice :func:`activate` made for this process."""
    return _ACTIVE if _ACTIVE is not None else CoreChoice(compiled=False, reason="pure Python (not activated)")


def activate() -> CoreChoice:
    """Put a current build in front of ``sitl.core.__path__`` and ``sitl.shell.__path__`` (once, first)."""
    global _ACTIVE  # noqa: PLW0603 - one decision per process
    if _ACTIVE is not None:
        return _ACTIVE
    already = [m for m in COMPILED_MODULES if f"sitl.{m}" in sys.modules]
    if already:
        choice = CoreChoice(compiled=False, reason=f"pure Python (core modules imported before activation: {already})")
    else:
        try:
            choice = choose(BUILD_DIR, sources_digest(), os.environ)
        except OSError as err:
            choice = CoreChoice(compiled=False, reason=f"pure Python (cannot read the sources or the build: {err})")
    if choice.compiled:
        try:
            (lib,) = BUILD_DIR.glob(f"{SHARED_LIB}.*.so")
            spec = importlib.util.spec_from_file_location(SHARED_LIB, lib)
            assert spec is not None
            assert spec.loader is not None
            module = importlib.util.module_from_spec(spec)
            sys.modules[SHARED_LIB] = module
            spec.loader.exec_module(module)
        except (ImportError, OSError, ValueError) as err:
            sys.modules.pop(SHARED_LIB, None)
            choice = CoreChoice(compiled=False, reason=f"pure Python (the compiled core does not load: {err})")
        else:
            for name in _SUBPACKAGES:
                package = importlib.import_module(f"sitl.{name}")  # their __init__ imports nothing
                package.__path__.insert(0, str(BUILD_DIR / "sitl" / name))
    if not choice.compiled and "older than the sources" in choice.reason:
        log.warning("SITL core: %s", choice.reason)
    _ACTIVE = choice
    return choice
