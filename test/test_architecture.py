"""The architecture as the code has it (docs/ARCHITECTURE.md §3): layers that tell the truth,
no import cycles, package.xml files that declare what the code imports, and a clean lint.

Read from the source with `ast`, nothing is imported:
- every import statement, anywhere in a file (module level, in functions, under try), and
  every import string: importlib.import_module("m"), __import__("m"), pytest.importorskip("m")
  and entry-point-like "package.module:attr" strings (setup.py entry points, `ciml` verbs);
- the three Python packages are layered ciml_learning ← ciml_control ← ciml_sim (ciml_msgs,
  the interfaces, below all): a file of a package (its modules, its tests, its setup.py) names
  no module of a package above it; tests that need several packages live in test/;
- no two modules import each other, directly or around a loop, at module level or inside functions.
"""
from __future__ import annotations

import ast
import configparser
import importlib.util
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAYERS = ("ciml_learning", "ciml_control", "ciml_sim")
"""The Python packages, lowest first: each may import those before it, never one after it."""

# "name = package.module:attr" or "package.module:attr" (an entry point or a verb's `run`)
ENTRY_POINT = re.compile(r"^\s*(?:[\w.-]+\s*=\s*)?([A-Za-z_]\w*(?:\.\w+)*):[A-Za-z_]\w*(?:\.\w+)*\s*$")
IMPORT_CALLS = {"import_module", "__import__", "importorskip"}


@dataclass(frozen=True)
class Import:
    file: str  # path relative to ROOT
    line: int
    target: str  # absolute dotted module name (for `from m import n`: m.n when that is a module, else m)
    kind: str  # "statement" or "string"
    local: bool  # inside a function (runs when called, not when the module is imported)
    typing_only: bool  # under `if TYPE_CHECKING:`
    optional: bool  # in a try whose handler catches ImportError

    def where(self) -> str:
        return f"{self.file}:{self.line}"


def _py_files(folder: str):
    for d, dirs, files in os.walk(folder):
        dirs[:] = sorted(x for x in dirs if x not in ("__pycache__", "build"))
        for f in sorted(files):
            if f.endswith(".py"):
                yield os.path.join(d, f)


def package_files(pkg: str) -> dict[str, list[str]]:
    """The files of a package: its modules, its tests and its setup.py."""
    base = os.path.join(ROOT, pkg)
    return {"modules": list(_py_files(os.path.join(base, pkg))), "tests": list(_py_files(os.path.join(base, "test"))),
            "setup": [os.path.join(base, "setup.py")]}


def module_name(path: str) -> str | None:
    """Dotted name of a package module (ciml_x/ciml_x/a/b.py → ciml_x.a.b); None for other files."""
    rel = os.path.relpath(path, ROOT).split(os.sep)
    if len(rel) < 3 or rel[0] not in LAYERS or rel[1] != rel[0]:
        return None
    parts = rel[1:]
    parts[-1] = parts[-1][:-3]
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES: dict[str, str] = {}  # dotted name → path, for every module of the three packages
for _pkg in LAYERS:
    for _path in package_files(_pkg)["modules"]:
        MODULES[module_name(_path)] = _path


def _resolve(name: str) -> str:
    """The module a dotted name lives in: the longest prefix that is a project module (or the name)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in MODULES:
            return ".".join(parts[:n])
    return name


def _catches_import_error(handler: ast.ExceptHandler) -> bool:
    names = []
    t = handler.type
    for node in (t.elts if isinstance(t, ast.Tuple) else [t]):
        if isinstance(node, ast.Name):
            names.append(node.id)
    return t is None or bool({"ImportError", "ModuleNotFoundError", "Exception"} & set(names))


def imports_of(path: str, me: str | None = None) -> list[Import]:
    """Every import of a file (statements and strings) with where it sits; `me`: the file's module
    name when it is not where module_name() looks."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), filename=path)
    rel = os.path.relpath(path, ROOT)
    me = me or module_name(path)
    is_pkg = path.endswith("__init__.py")
    out: list[Import] = []

    def base_for(level: int) -> str:
        parts = (me or "").split(".")
        keep = len(parts) - level + (1 if is_pkg else 0)
        return ".".join(parts[:keep])

    def visit(node: ast.AST, local: bool, typing_only: bool, optional: bool) -> None:
        def add(target: str, kind: str, line: int) -> None:
            out.append(Import(rel, line, target, kind, local, typing_only, optional))

        if isinstance(node, ast.Import):
            for a in node.names:
                add(_resolve(a.name) if a.name.split(".")[0] in LAYERS else a.name, "statement", node.lineno)
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:
                mod = base_for(node.level) + ("." + mod if mod else "")
            for a in node.names:
                full = f"{mod}.{a.name}"
                add(full if full in MODULES else (_resolve(mod) if mod.split(".")[0] in LAYERS else mod),
                    "statement", node.lineno)
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if name in IMPORT_CALLS:
                add(node.args[0].value, "string", node.lineno)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            m = ENTRY_POINT.match(node.value)
            if m:
                add(m.group(1), "string", node.lineno)

        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            local = True
        if isinstance(node, ast.If):
            test = node.test
            if (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
                    (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"):
                for child in node.body:
                    visit(child, local, True, optional)
                for child in node.orelse:
                    visit(child, local, typing_only, optional)
                return
        if isinstance(node, ast.Try):
            opt = any(_catches_import_error(h) for h in node.handlers)
            for child in node.body:
                visit(child, local, typing_only, optional or opt)
            for child in [*node.handlers, *node.orelse, *node.finalbody]:
                visit(child, local, typing_only, optional)
            return
        for child in ast.iter_child_nodes(node):
            visit(child, local, typing_only, optional)

    visit(tree, False, False, False)
    return out


def _layer(name: str) -> int | None:
    top = name.split(".")[0]
    return LAYERS.index(top) if top in LAYERS else None


# --- (a) layers ------------------------------------------------------------------------------------


def test_the_import_scanner_sees_statements_strings_and_context(tmp_path):
    """The scanner itself: a check that finds nothing must be able to find something."""
    probe = tmp_path / "probe.py"
    probe.write_text("import importlib\nfrom . import topics\nfrom ..diagnosis import run\n"
                     "def f():\n    import ciml_sim.plant\n    importlib.import_module('ciml_control.qp')\n"
                     "    return 'ciml_sim.commands:record'\n"
                     "try:\n    import lz4\nexcept ImportError:\n    pass\n")
    got = {(i.target, i.kind, i.local, i.optional) for i in imports_of(str(probe), me="ciml_learning.core.probe")}
    assert got == {("importlib", "statement", False, False), ("ciml_learning.core.topics", "statement", False, False),
                   ("ciml_learning.diagnosis.run", "statement", False, False),
                   ("ciml_sim.plant", "statement", True, False), ("ciml_control.qp", "string", True, False),
                   ("ciml_sim.commands", "string", True, False), ("lz4", "statement", False, True)}


def test_no_package_imports_one_above_it_by_any_means():
    upward = []
    for pkg in LAYERS:
        mine = LAYERS.index(pkg)
        for files in package_files(pkg).values():
            for path in files:
                for imp in imports_of(path):
                    layer = _layer(imp.target)
                    if layer is not None and layer > mine:
                        upward.append(f"{imp.where()}: {pkg} → {imp.target} ({imp.kind}"
                                      f"{', in a function' if imp.local else ''})")
    assert not upward, "upward imports (move the code or the test up, or register it where it lives):\n" + \
        "\n".join(upward)


def names_of_packages_above(path: str, above: tuple[str, ...]) -> list[str]:
    """String constants of a file that name a package of `above` as data ("ciml_sim", "ciml_sim/…",
    "ciml_sim.x"), e.g. to find its share folder or executables at run time; documentation
    (docstrings and other bare string statements) is left out."""
    if not above:
        return []
    pattern = re.compile(rf"^({'|'.join(above)})([./:]|$)")
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}
    return [f"{os.path.relpath(path, ROOT)}:{n.lineno}: {n.value!r}" for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
            and pattern.match(n.value.strip())]


def test_the_name_finder_sees_data_not_documentation(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""Uses ciml_sim."""\nPKG = "ciml_sim"\nX = "ciml_sim/launch"\n"""ciml_sim: doc."""\n'
                 'def g():\n    """ciml_sim"""\n    return "ciml_simulator", "about ciml_sim"\n')
    assert [h.split(": ", 1)[1] for h in names_of_packages_above(str(f), ("ciml_sim",))] == \
        ["'ciml_sim'", "'ciml_sim/launch'"]


def test_no_package_module_names_a_package_above_it_in_a_string():
    """ARCHITECTURE.md: nothing names a package above it, not even in a string (a launch file or an
    executable found by name at run time is a dependency all the same)."""
    named = [hit for i, pkg in enumerate(LAYERS) for path in package_files(pkg)["modules"]
             for hit in names_of_packages_above(path, LAYERS[i + 1:])]
    assert not named, "\n".join(named)


def private_imports(path: str) -> list[str]:
    """`from <a ciml module> import _name` in a file: another module's private name (the module
    should make it public, or keep the code that needs it)."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    return [f"{os.path.relpath(path, ROOT)}:{n.lineno}: {'.' * n.level}{n.module or ''} {a.name}"
            for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
            and (n.level > 0 or (n.module or "").split(".")[0] in LAYERS)
            for a in n.names if a.name.startswith("_") and not a.name.startswith("__")]


def test_no_module_imports_a_private_name_of_another(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("from .report import _where\nfrom ciml_learning.cli.main import main, _join\nfrom os import _exit\n")
    assert [h.split(": ", 1)[1] for h in private_imports(str(f))] == [".report _where", "ciml_learning.cli.main _join"]
    found = [hit for pkg in LAYERS for path in package_files(pkg)["modules"] for hit in private_imports(path)]
    assert not found, "\n".join(found)


FLOORS = ("core", "effects", "logs", "learning", "diagnosis", "ros", "nodes", "cli")
"""ciml_learning's floors (subpackages), lowest first (docs/ARCHITECTURE.md §3): a module imports
only its own floor and those below it (the package's own __init__ is below all of them)."""


def _floor(module: str) -> int | None:
    """Floor index of a ciml_learning module (−1: the package itself; None: another package)."""
    parts = module.split(".")
    if parts[0] != "ciml_learning":
        return None
    return -1 if len(parts) == 1 else FLOORS.index(parts[1]) if parts[1] in FLOORS else len(FLOORS)


def floor_violations(path: str, me: str) -> list[str]:
    """Imports (statements anywhere, import and entry-point strings) and string constants (not
    docstrings) of module `me` that name a ciml_learning floor above its own."""
    mine = _floor(me)
    assert mine is not None and mine < len(FLOORS), f"{me} sits in no floor of {FLOORS}"
    rel = os.path.relpath(path, ROOT)
    out = [f"{imp.where()}: {me} → {imp.target} ({imp.kind}{', in a function' if imp.local else ''})"
           for imp in imports_of(path, me=me) if (_floor(imp.target) or 0) > mine]
    above = FLOORS[mine + 1:]
    if above:
        out += [f"{rel}:{hit.split(':', 2)[1]}: {me} names {hit.split(': ', 1)[1]}"
                for hit in names_of_packages_above(path, tuple(f"ciml_learning[.]{f}" for f in above))]
    return out


def test_the_floor_rule_finds_an_import_and_a_string_from_above(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""Not ciml_learning.cli: a docstring."""\nfrom ciml_learning.core import robot\n'
                 'def g():\n    from ciml_learning.learning.models import ModelSet\n'
                 '    return "ciml_learning.cli.commands:extract", "ciml_learning.ros.launcher"\n')
    found = floor_violations(str(f), "ciml_learning.core.m")
    assert len(found) == 4 and "ciml_learning.learning.models" in found[0], found
    assert floor_violations(str(f), "ciml_learning.cli.m") == []


def test_every_ciml_learning_module_sits_in_a_floor_and_imports_none_above_it():
    """Floors as folders: what a module may use is where it lives (strings included)."""
    found = [hit for m, path in MODULES.items() if m.startswith("ciml_learning.")
             for hit in floor_violations(path, m)]
    assert not found, "imports from a floor above (move the code down, or the caller up):\n" + "\n".join(found)


def floor_graph() -> dict[tuple[str, str], int]:
    """(importing floor, imported floor) → how many (module, module) imports join them."""
    edges: dict[tuple[str, str], int] = {}
    for m, path in MODULES.items():
        a = _floor(m)
        for b in [_floor(t) for t in {i.target for i in imports_of(path, me=m)}]:
            if a is not None and b is not None and 0 <= a < len(FLOORS) and 0 <= b < len(FLOORS) and a != b:
                edges[FLOORS[a], FLOORS[b]] = edges.get((FLOORS[a], FLOORS[b]), 0) + 1
    return edges


def test_the_floor_graph_of_architecture_md_is_the_code_s():
    """docs/ARCHITECTURE.md §3 draws the imports between floors with their counts: as the code has them."""
    with open(os.path.join(ROOT, "docs", "ARCHITECTURE.md"), encoding="utf-8") as f:
        drawn = {(a, b): int(n) for a, n, b in re.findall(r"^  (\w+) -->\|(\d+)\| (\w+)$", f.read(), re.M)}
    assert drawn == floor_graph(), "regenerate with results/house/import_graph.py HEAD"


ROS_FLOORS = ("ros", "nodes")
"""The floors that may use the ROS client library; below them only rclpy.serialization (a bag's
messages are CDR as rclpy writes them), so the algorithms run and are tested without a graph."""


def test_only_the_ros_floors_use_rclpy():
    found = [f"{imp.where()}: {m} → {imp.target}" for m, path in MODULES.items()
             if m.startswith("ciml_learning.") and m.split(".")[1] not in ROS_FLOORS
             for imp in imports_of(path, me=m)
             if imp.target.split(".")[0] == "rclpy" and imp.target != "rclpy.serialization"]
    assert not found, "rclpy outside ros/ and nodes/:\n" + "\n".join(found)


NODE_START_UP_SCIPY = {"ciml_learning.nodes.state_filter": {"scipy.ndimage", "scipy.signal"}}
"""The scipy subpackages a node's process loads before it spins: only the state filter's FIR
design (scipy.signal.firls for the profile's rate; the filters' module also uses scipy.ndimage).
Each costs a process 0.2–0.5 s of CPU at start-up, when every node of a graph starts at once on
two cores; scipy itself is light (numba imports it)."""


def node_modules() -> list[str]:
    """The modules of the node classes that the packages register ("ciml.nodes" entry points)."""
    found = []
    for pkg in LAYERS:
        with open(os.path.join(ROOT, pkg, "setup.py"), encoding="utf-8") as f:
            block = re.search(r'"ciml\.nodes": \[(.*?)\]', f.read(), re.S)
        found += re.findall(r"=\s*([\w.]+):", block.group(1)) if block else []
    return found


def loaded_at_import(module: str) -> set[str]:
    """Every module a `import module` runs: its module-level imports, its packages', transitively."""
    seen: set[str] = set()
    todo = [module]
    while todo:
        m = todo.pop()
        parts = m.split(".")
        for name in [".".join(parts[:n]) for n in range(1, len(parts) + 1)]:
            if name in seen:
                continue
            seen.add(name)
            if name in MODULES:
                todo += [i.target for i in imports_of(MODULES[name], me=name) if not i.local and not i.typing_only
                         and i.kind == "statement"]
    return seen


def test_nodes_load_no_scipy_subpackage_they_do_not_need():
    nodes = node_modules()
    assert "ciml_sim.bridge_node" in nodes and "ciml_learning.nodes.state_filter" in nodes
    found = {m: sorted(s for s in loaded_at_import(m) if s.startswith("scipy.")
                       and s not in NODE_START_UP_SCIPY.get(m, set())) for m in nodes}
    assert not any(found.values()), f"import them where they are used: {found}"


def test_no_package_declares_a_package_above_it():
    for pkg in LAYERS:
        above = set(LAYERS[LAYERS.index(pkg) + 1:])
        declared = {d for _, d in _dependencies(pkg)}
        assert not declared & above, (pkg, declared & above)


# --- (a) cycles ------------------------------------------------------------------------------------


def _graph() -> dict[str, set[str]]:
    """Module → the project modules it imports, at module level or inside functions (a function-local
    import closes a cycle as surely, only later); typing-only imports and import strings left out."""
    g: dict[str, set[str]] = {m: set() for m in MODULES}
    for m, path in MODULES.items():
        for imp in imports_of(path):
            if imp.kind != "statement" or imp.typing_only:
                continue
            if imp.target in MODULES and imp.target != m:
                g[m].add(imp.target)
    return g


def _cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on, stack, out = set(), [], []
    counter = [0]
    for root in sorted(g):
        if root in index:
            continue
        work = [(root, iter(sorted(g[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(g[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return sorted(out)


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_modules():
    cycles = _cycles(_graph())
    assert not cycles, f"import cycles (function-local imports included): {cycles}"


# --- (b) package.xml declares what the code imports ------------------------------------------------

ROS_PACKAGES = {"rclpy", "ament_index_python", "builtin_interfaces", "rcl_interfaces", "std_msgs", "sensor_msgs",
                "nav_msgs", "geometry_msgs", "diagnostic_msgs", "rosgraph_msgs", "std_srvs", "tf2_msgs", "ciml_msgs",
                *LAYERS}
"""Imported under their ROS package name, which is their rosdep key."""
ROSDEP_KEYS = {
    # keys of ros/rosdistro rosdep/python.yaml
    "numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml", "matplotlib": "python3-matplotlib",
    "joblib": "python3-joblib", "numba": "python3-numba", "tqdm": "python3-tqdm", "pytest": "python3-pytest",
    "dask": "python3-dask",  # dask.distributed: Debian's python3-distributed, rosdep's python3-dask key
    # ROS packages of the distribution (Jazzy releases pinocchio and proxsuite)
    "pinocchio": "pinocchio", "proxsuite": "proxsuite",
    # no key found in rosdep/python.yaml: the conventional pip key python3-<name>-pip (installed here by
    # requirements.txt); to be added to rosdistro (or a local rosdep source) before `rosdep install` resolves them
    "GPy": "python3-gpy-pip", "rosbags": "python3-rosbags-pip", "mujoco": "python3-mujoco-pip",
    "llvmlite": "python3-llvmlite-pip", "threadpoolctl": "python3-threadpoolctl-pip", "lz4": "python3-lz4-pip",
    "backports": "python3-backports-zstd-pip",  # backports.zstd, the only backport imported
}
LATER_STDLIB = {"compression"}
"""compression.zstd: standard library from Python 3.14 (mcap_check tries it before backports.zstd)."""


def _dependencies(pkg: str) -> list[tuple[str, str]]:
    root = ET.parse(os.path.join(ROOT, pkg, "package.xml")).getroot()
    return [(el.tag, (el.text or "").strip()) for el in root if el.tag.endswith("depend")]


def _import_key(target: str, local_helpers: set[str]) -> str | None:
    """The rosdep key an import needs; None for the standard library and the test helpers."""
    top = target.split(".")[0]
    if top in sys.stdlib_module_names or top in LATER_STDLIB or top in local_helpers or top == "__future__":
        return None
    if top in ROS_PACKAGES:
        return top
    return ROSDEP_KEYS.get(top, f"<no rosdep key known for import {top!r}: add one to ROSDEP_KEYS>")


@pytest.mark.parametrize("pkg", LAYERS)
def test_package_xml_declares_every_import(pkg):
    deps = _dependencies(pkg)
    runtime = {d for tag, d in deps if tag in ("depend", "exec_depend")}
    testing = runtime | {d for tag, d in deps if tag == "test_depend"}
    helpers = {os.path.basename(p)[:-3] for p in [*_py_files(os.path.join(ROOT, pkg, "test")),
                                                  *_py_files(os.path.join(ROOT, "test"))]}
    files = package_files(pkg)
    missing = set()
    for kind, need in (("modules", runtime), ("tests", testing)):
        for path in files[kind]:
            for imp in imports_of(path):
                if imp.kind != "statement" or imp.typing_only:
                    continue
                key = _import_key(imp.target, helpers if kind == "tests" else set())
                if key is not None and key != pkg and key not in need:
                    tag = "exec_depend" if kind == "modules" else "test_depend"
                    missing.add(f"<{tag}>{key}</{tag}>  ({imp.where()}: import {imp.target})")
    assert not missing, f"{pkg}/package.xml lacks:\n" + "\n".join(sorted(missing))


def test_import_key_mapping():
    assert _import_key("os.path", set()) is None and _import_key("rosutil", {"rosutil"}) is None
    assert _import_key("sensor_msgs.msg", set()) == "sensor_msgs"
    assert _import_key("backports", set()) == "python3-backports-zstd-pip"
    assert "no rosdep key" in _import_key("somethingnew", set())


# --- (c) lint --------------------------------------------------------------------------------------

def _tracked_python_files() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    except OSError:
        out = None
    files = out.stdout.split() if out is not None and out.returncode == 0 else []
    return files or ["."]  # not a git checkout: the whole tree


def _ruff() -> subprocess.CompletedProcess:
    assert _has_ruff_module(), "ruff is not installed (requirements.txt pins it; run make install)"
    return subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise",
                           *_tracked_python_files()], cwd=ROOT, capture_output=True, text=True, timeout=600)


def _has_ruff_module() -> bool:
    return importlib.util.find_spec("ruff") is not None


def test_ruff_is_clean():
    """ruff.toml's rules (E, F, W, I; lines up to 120 columns) over every tracked Python file."""
    r = _ruff()
    assert r.returncode == 0, r.stdout + r.stderr


# --- (d) types -------------------------------------------------------------------------------------


def _mypy(*files: str) -> subprocess.CompletedProcess:
    assert importlib.util.find_spec("mypy") is not None, \
        "mypy is not installed (requirements.txt pins it; run make install)"
    return subprocess.run([sys.executable, "-m", "mypy", "--config-file", os.path.join(ROOT, "mypy.ini"), *files],
                          cwd=ROOT, capture_output=True, text=True, timeout=1200)


def test_mypy_finds_a_type_error(tmp_path):
    """The check itself: with the project's configuration, a wrong type is an error."""
    probe = tmp_path / "probe.py"
    probe.write_text('from ciml_learning.core.robot import load_robot\n\nn_joints: str = load_robot().n_joints\n')
    r = _mypy(str(probe))
    assert r.returncode == 1 and "Incompatible types in assignment" in r.stdout, r.stdout + r.stderr


def test_mypy_is_clean():
    """mypy.ini's modules (every module of the three packages, nodes included, and tools/) type-check."""
    r = _mypy()
    assert r.returncode == 0, r.stdout + r.stderr


def test_mypy_checks_every_module_of_ours():
    """mypy.ini leaves out no module of ours: every tracked Python file of the packages and tools/
    is under its files, nothing is excluded, and no module of ours is only followed silently
    (the nodes, the tools and the ROS adapters were each left out once)."""
    cfg = configparser.ConfigParser()
    cfg.read(os.path.join(ROOT, "mypy.ini"))
    files = [f.strip() for f in cfg["mypy"]["files"].split(",")]
    assert "exclude" not in cfg["mypy"], f"mypy.ini excludes {cfg['mypy']['exclude']}"
    packages = ("ciml_learning", "ciml_control", "ciml_sim")
    ours = [p for p in _tracked_python_files() if p.startswith(tuple(f"{k}/{k}/" for k in packages) + ("tools/",))]
    assert len(ours) > 100
    for path in ours:
        assert any(path.startswith(f + "/") for f in files), f"{path}: not under mypy.ini's files"
    for section in cfg.sections():
        if cfg[section].get("follow_imports") in ("silent", "skip"):
            assert not any(m.strip().startswith(packages) for m in section.removeprefix("mypy-").split(",")), section
