"""The project's layering rules, checked on source text (``ast``), and the one declared allow-list.

``tests/unit/test_layering.py`` runs :func:`check` over the real tree; its own tests build
small trees with each kind of violation and show that the checker reports it. The rules:

1. **Allow-list.** A package's runtime code imports only the standard library, itself and
   what :func:`project_packages` allows it (project packages, ROS packages, third-party libraries).
2. **Pure cores.** A module under ``<package>/core/`` imports nothing that does I/O, keeps
   time or talks to ROS (:data:`CORE_FORBIDDEN`, any ``*_msgs``/``*_srvs``), only the pure
   modules of the project (any ``core/``, a package's ``errors``, :data:`PURE_COMMON`), uses
   no global random state (``random``, ``np.random.<fn>``: generators are passed in) and
   neither prints nor exits.
3. **ROS only at the edges.** rospy and ROS message packages are imported only in ``ros/``,
   ``nodes/`` and ``cli/`` folders (a CLI may talk to a ROS graph).
4. **No cycles** between the project's modules (function-level imports count; imports under
   ``if TYPE_CHECKING:`` do not, they never run).
5. **No private names across modules**: ``from a.b import _c`` only inside ``a.b`` itself.
6. **Library code never prints or exits** (everything but ``cli``, ``nodes`` and ``__main__``).
7. **package.xml says exactly what runs**: a catkin package's run dependencies (``depend`` and
   ``exec_depend``) are the ROS packages its Python code imports, the packages its launch files
   start or include, and the few it runs as commands (:data:`COMMAND_DEPENDS`, with the reason).
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "CORE_FORBIDDEN",
    "PURE_COMMON",
    "Package",
    "Violation",
    "check",
    "project_packages",
]

#: Imports that do I/O, keep time, run processes, draw or talk to ROS: never in a ``core/`` module.
CORE_FORBIDDEN = frozenset(
    {
        "asyncio", "concurrent", "datetime", "ftplib", "http", "multiprocessing", "os", "random", "sched", "select",
        "selectors", "shutil", "signal", "socket", "socketserver", "subprocess", "tempfile", "threading", "time",
        "urllib", "xmlrpc", "dask", "distributed",
        "cv_bridge", "genpy", "jsbsim", "matplotlib", "mavsdk", "moderngl", "pymavlink", "rosbag", "rosbags",
        "rosgraph", "roslaunch", "rospy", "serial", "tf2_ros", "trimesh",
    }
)  # fmt: skip
#: uav_common's pure modules (a core may import these; not ``paths``, ``waiting``, ``mavlink_parser``,
#: ``ros.*`` or ``shell.*``, which read the environment, keep time or talk to processes).
PURE_COMMON = frozenset(
    {
        "uav_common",
        "uav_common.autopilot_modes",
        "uav_common.config",
        "uav_common.detection_classes",
        "uav_common.errors",
        "uav_common.exit_codes",
        "uav_common.frames",
        "uav_common.geo",
        "uav_common.lockstep",
        "uav_common.lockstep.markers",
        "uav_common.lockstep.protocol",
        "uav_common.lockstep.timers",
        "uav_common.pointcloud",
        "uav_common.robot",
        "uav_common.rotations",
        "uav_common.validate",
        "uav_common.voxel_keys",
    }
)
#: Folders where rospy and ROS messages may be imported.
ROS_FOLDERS = frozenset({"ros", "nodes", "cli"})
#: Modules that are not library code: they may print and exit.
ENTRY_FOLDERS = frozenset({"cli", "nodes"})

_NUMPY_RNG_OK = frozenset({"default_rng", "Generator", "SeedSequence", "PCG64", "BitGenerator"})


@dataclass(frozen=True)
class Package:
    """One Python package of the project and what its runtime code may import."""

    name: str
    src: Path  # the folder holding the package folder
    may_import: frozenset[str]
    catkin: Path | None = None  # the catkin package folder (with package.xml), if it is one
    #: Run dependencies of the catkin package that are neither imported nor launched, with why.
    command_depends: Mapping[str, str] = field(default_factory=dict)

    @property
    def root(self) -> Path:
        return self.src / self.name


@dataclass(frozen=True)
class Violation:
    rule: str
    where: str
    what: str

    def __str__(self) -> str:
        return f"[{self.rule}] {self.where}: {self.what}"


ROS_COMMON = frozenset({"rospy", "std_msgs", "geometry_msgs", "sensor_msgs", "nav_msgs", "uav_msgs"})
NUMERIC = frozenset({"numpy", "scipy", "cv2", "yaml"})


def project_packages(repo: Path) -> list[Package]:
    """The declared allow-list: every package of the project and what it may import at run time."""
    ws = repo / "catkin_ws" / "src"

    def catkin(name: str) -> tuple[Path, Path]:
        return ws / name / "src", ws / name

    common = Package(
        "uav_common",
        repo / "uav_common" / "src",
        # rosgraph, tf2_ros, tf2_msgs, std_msgs and uav_msgs: the causal lockstep's ROS shell (ros/lockstep.py)
        frozenset(
            {
                "numpy",
                "yaml",
                "pymavlink",
                "rospy",
                "rosgraph",
                "sensor_msgs",
                "std_msgs",
                "tf2_ros",
                "tf2_msgs",
                "uav_msgs",
            }
        ),
    )
    sitl = Package(
        "sitl",
        repo / "sitl" / "src",
        frozenset({"uav_common", "numpy", "yaml", "jsbsim", "pymavlink", "fastcrc"}),
    )
    router = Package(
        "mavlink_router",
        repo / "mavlink_router" / "src",
        frozenset({"uav_common", "pymavlink", "fastcrc", "serial"}),
    )
    src, pkg = catkin("uav_sim_bridge")
    bridge = Package(
        "uav_sim_bridge",
        src,
        frozenset(
            {"uav_common", *NUMERIC, "moderngl", "trimesh", "PIL", "pymavlink", *ROS_COMMON, "rosgraph"}
            | {"rosgraph_msgs", "tf2_ros", "visualization_msgs", "vision_msgs"}
        ),
        pkg,
    )
    src, pkg = catkin("uav_autonomy")
    autonomy = Package(
        "uav_autonomy",
        src,
        frozenset({"uav_common", *NUMERIC, "pymavlink", *ROS_COMMON, "tf2_ros"}),
        pkg,
    )
    src, pkg = catkin("uav_perception")
    perception = Package(
        "uav_perception",
        src,
        # onnxruntime runs the learned detector (shell/); torch and onnx train and export it (training/, the
        # opt-in requirements-train.txt); pycocotools and matplotlib score and plot a trained model (training/)
        frozenset({"uav_common", *NUMERIC, *ROS_COMMON, "tf2_ros", "vision_msgs", "onnxruntime"})
        | {"torch", "onnx", "pycocotools", "matplotlib"},
        pkg,
    )
    src, pkg = catkin("uav_scenarios")
    scenarios = Package(
        "uav_scenarios",
        src,
        frozenset(
            {"uav_common", "uav_autonomy", "uav_perception", "uav_sim_bridge", *NUMERIC, "matplotlib", "motmetrics"}
            | {"pymavlink", "mavlink_router"}
            | {"pycocotools", "rosbags"}
            | {*ROS_COMMON, "rosgraph", "rosgraph_msgs", "rosbag"}
        ),
        pkg,
        command_depends={
            "rosbag": "scenario_record and scenario_play run `rosbag record` and `rosbag play`",
            "roslaunch": "uav-run starts `roslaunch uav_scenarios <mission>.launch`",
        },
    )
    src, pkg = catkin("uav_campaigns")
    campaigns = Package(
        "uav_campaigns",
        src,
        # dask and distributed in shell/ only (CORE_FORBIDDEN); uav-run is started as a program, not imported
        frozenset({"uav_common", "uav_scenarios", "numpy", "scipy", "yaml", "matplotlib", "distributed", "dask"}),
        pkg,
    )
    src, pkg = catkin("uav_datasets")
    datasets = Package(
        "uav_datasets",
        src,
        # zlib_ng: zlib-ng's deflate for the PNGs (shell/writers.py)
        frozenset({"uav_common", "uav_sim_bridge", "uav_scenarios", *NUMERIC, "rosbags", "pycocotools", "zlib_ng"}),
        pkg,
    )
    return [common, sitl, router, bridge, autonomy, perception, scenarios, campaigns, datasets]


# ---------------------------------------------------------------------------------------------- parsing


@dataclass(frozen=True)
class _Import:
    module: str  # absolute dotted name of the module or package imported from
    names: tuple[str, ...]  # names imported from it (``from m import a, b``); () for ``import m``
    line: int


@dataclass
class _Module:
    name: str
    path: Path
    package: Package
    imports: list[_Import]
    tree: ast.Module

    @property
    def parts(self) -> tuple[str, ...]:
        return tuple(self.name.split("."))

    def in_folder(self, folder: str) -> bool:
        return folder in self.parts[1:-1] or (self.path.name == "__init__.py" and self.parts[-1] == folder)

    @property
    def is_core(self) -> bool:
        return self.in_folder("core")

    @property
    def is_entry(self) -> bool:
        return any(self.in_folder(f) for f in ENTRY_FOLDERS) or self.parts[-1] in ("__main__", "cli")


def _type_checking_lines(tree: ast.Module) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If):
            test = node.test
            name = test.id if isinstance(test, ast.Name) else test.attr if isinstance(test, ast.Attribute) else ""
            if name == "TYPE_CHECKING":
                for child in node.body:
                    for sub in ast.walk(child):
                        if hasattr(sub, "lineno"):
                            lines.add(sub.lineno)
    return lines


def _imports(tree: ast.Module, module: str, is_package: bool) -> list[_Import]:
    skip = _type_checking_lines(tree)
    out: list[_Import] = []
    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in skip:
            continue
        if isinstance(node, ast.Import):
            out.extend(_Import(alias.name, (), node.lineno) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_package else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            out.append(_Import(target, tuple(a.name for a in node.names), node.lineno))
    return out


def _modules(pkg: Package) -> Iterator[_Module]:
    for path in sorted(pkg.root.rglob("*.py")):
        rel = path.relative_to(pkg.src).with_suffix("")
        parts = list(rel.parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        name = ".".join(parts)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        yield _Module(name, path, pkg, _imports(tree, name, is_package), tree)


# ---------------------------------------------------------------------------------------------- rules


def _top(name: str) -> str:
    return name.split(".", maxsplit=1)[0]


def _resolve(imp: _Import, known: Mapping[str, _Module]) -> list[str]:
    """The project modules an import executes: ``from a.b import c`` is ``a.b.c`` when that is a module."""
    if imp.names:
        subs = [f"{imp.module}.{n}" for n in imp.names if f"{imp.module}.{n}" in known]
        if subs:
            return subs
    return [imp.module] if imp.module in known else []


def _is_ros_package(name: str, catkin_names: Iterable[str]) -> bool:
    return name in set(catkin_names) or (Path("/usr/share") / name / "package.xml").is_file()


def _check_allow_list(mod: _Module) -> Iterator[Violation]:
    own = mod.package.name
    for imp in mod.imports:
        top = _top(imp.module)
        if top in sys.stdlib_module_names or top in (own, "__future__"):
            continue
        if top not in mod.package.may_import:
            yield Violation(
                "allow-list",
                f"{mod.path}:{imp.line}",
                f"{mod.name} imports {imp.module}, which {own} may not import (tests/helpers/layering.py)",
            )


def _check_core(mod: _Module, known: Mapping[str, _Module]) -> Iterator[Violation]:
    if not mod.is_core:
        return
    for imp in mod.imports:
        top = _top(imp.module)
        where = f"{mod.path}:{imp.line}"
        if top in CORE_FORBIDDEN or top.endswith(("_msgs", "_srvs")):
            yield Violation("pure-core", where, f"core module {mod.name} imports {imp.module}")
            continue
        for target in _resolve(imp, known):
            t = known[target]
            pure = t.is_core or t.parts[-1] == "errors" or target in PURE_COMMON
            if not pure:
                yield Violation("pure-core", where, f"core module {mod.name} imports {target}, which is not pure")
    for node in ast.walk(mod.tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Attribute)
            and node.value.attr == "random"
            and isinstance(node.value.value, ast.Name)
            and node.value.value.id in ("np", "numpy")
            and node.attr not in _NUMPY_RNG_OK
        ):
            yield Violation(
                "pure-core", f"{mod.path}:{node.lineno}", f"{mod.name} uses the global np.random.{node.attr}"
            )


def _check_ros_edges(mod: _Module, catkin_names: Iterable[str]) -> Iterator[Violation]:
    if any(mod.in_folder(f) for f in ROS_FOLDERS):
        return
    names = list(catkin_names)
    for imp in mod.imports:
        top = _top(imp.module)
        if top in ("rospy", "rosbag", "roslaunch", "tf2_ros") or (
            top.endswith(("_msgs", "_srvs")) and _is_ros_package(top, names)
        ):
            yield Violation(
                "ros-edges",
                f"{mod.path}:{imp.line}",
                f"{mod.name} imports {imp.module} outside a ros/, nodes/ or cli/ folder",
            )


def _check_private(mod: _Module, known: Mapping[str, _Module]) -> Iterator[Violation]:
    for imp in mod.imports:
        if imp.module == mod.name or _top(imp.module) not in {m.package.name for m in known.values()}:
            continue
        for name in imp.names:
            if name.startswith("_") and not (name.startswith("__") and name.endswith("__")):
                yield Violation(
                    "private-name", f"{mod.path}:{imp.line}", f"{mod.name} imports private {name} from {imp.module}"
                )


def _check_no_print_exit(mod: _Module) -> Iterator[Violation]:
    if mod.is_entry:
        return
    for node in ast.walk(mod.tree):
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Name) and f.id in ("print", "exit", "quit"):
                yield Violation("no-print-exit", f"{mod.path}:{node.lineno}", f"{mod.name} calls {f.id}()")
            if (
                isinstance(f, ast.Attribute)
                and isinstance(f.value, ast.Name)
                and (f.value.id, f.attr)
                in (
                    ("sys", "exit"),
                    ("os", "_exit"),
                )
            ):
                yield Violation(
                    "no-print-exit", f"{mod.path}:{node.lineno}", f"{mod.name} calls {f.value.id}.{f.attr}()"
                )


def _cycles(modules: Mapping[str, _Module]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    graph = {
        name: sorted({t for imp in m.imports for t in _resolve(imp, modules) if t != name})
        for name, m in modules.items()
    }
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work: list[tuple[str, int]] = [(start, 0)]
        while work:
            node, i = work.pop()
            if i == 0:
                index[node] = low[node] = counter
                counter += 1
                stack.append(node)
                on_stack.add(node)
            edges = graph[node]
            if i < len(edges):
                work.append((node, i + 1))
                nxt = edges[i]
                if nxt not in index:
                    work.append((nxt, 0))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            if low[node] == index[node]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
    return out


def _launch_references(pkg_dir: Path) -> set[str]:
    refs: set[str] = set()
    for launch in pkg_dir.glob("launch/*.launch"):
        root = ET.parse(launch).getroot()
        for el in root.iter():
            if el.tag == "node" and el.get("pkg"):
                refs.add(str(el.get("pkg")))
            for attr in ("file", "value", "default", "command", "args"):
                text = el.get(attr) or ""
                start = 0
                while (i := text.find("$(find ", start)) >= 0:
                    j = text.find(")", i)
                    refs.add(text[i + 7 : j].strip())
                    start = j
    return refs


def _declared_run_depends(pkg_dir: Path) -> set[str]:
    root = ET.parse(pkg_dir / "package.xml").getroot()
    return {str(e.text).strip() for e in root if e.tag in ("depend", "exec_depend", "run_depend") and e.text}


def _check_package_xml(pkg: Package, modules: Iterable[_Module], catkin_names: set[str]) -> Iterator[Violation]:
    if pkg.catkin is None:
        return
    imported = {
        _top(imp.module)
        for m in modules
        for imp in m.imports
        if _top(imp.module) != pkg.name and _is_ros_package(_top(imp.module), catkin_names)
    }
    launched = _launch_references(pkg.catkin) - {pkg.catkin.name}
    needed = imported | launched | set(pkg.command_depends)
    declared = _declared_run_depends(pkg.catkin)
    declared_ros = {d for d in declared if _is_ros_package(d, catkin_names)}
    where = str(pkg.catkin / "package.xml")
    for missing in sorted(needed - declared_ros):
        why = "imported" if missing in imported else "used by a launch file" if missing in launched else "run"
        yield Violation("package-xml", where, f"{missing} is {why} but not a run dependency")
    for extra in sorted(declared_ros - needed):
        yield Violation("package-xml", where, f"{extra} is declared but nothing imports, launches or runs it")


def check(packages: list[Package]) -> list[Violation]:
    """Every violation of the rules in the packages (empty: the layering holds)."""
    catkin_names = {p.catkin.name for p in packages if p.catkin is not None}
    for p in packages:
        if p.catkin is not None:
            catkin_names |= {d.name for d in p.catkin.parent.iterdir() if (d / "package.xml").is_file()}
    modules: dict[str, _Module] = {}
    per_package: dict[str, list[_Module]] = {}
    for pkg in packages:
        mods = list(_modules(pkg))
        per_package[pkg.name] = mods
        modules.update({m.name: m for m in mods})
    out: list[Violation] = []
    for mod in modules.values():
        out.extend(_check_allow_list(mod))
        out.extend(_check_core(mod, modules))
        out.extend(_check_ros_edges(mod, catkin_names))
        out.extend(_check_private(mod, modules))
        out.extend(_check_no_print_exit(mod))
    out.extend(Violation("cycle", " -> ".join(c), "import cycle") for c in _cycles(modules))
    for pkg in packages:
        out.extend(_check_package_xml(pkg, per_package[pkg.name], catkin_names))
    return out
