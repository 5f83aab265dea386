"""ciml_learning's import graph by floor at a git revision, for docs/ARCHITECTURE.md §3.

    python results/house/import_graph.py REV [REV ...]

For each revision: every import between ciml_learning modules (module level and inside
functions) counted by (importer's floor → imported module's floor), and the imports that go up
a floor. Before the floors existed (the flat package) a module is placed on the floor its
namesake sits on today (cli.py → cli/main, cliargs → cli/args; learning_commands, commands
and diagnosis/commands → cli, launcher → cli (its verb) as the floors commit moved them), so
the same rule is applied to both layouts. Prints a Markdown table and a Mermaid graph.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from collections import Counter

FLOORS = ("core", "effects", "logs", "learning", "diagnosis", "ros", "nodes", "cli")
PKG = "ciml_learning/ciml_learning/"
RENAMED = {"cli": "cli", "cliargs": "cli", "commands": "cli", "learning_commands": "cli", "launcher": "cli",
           "inspect_log": "cli", "bench": "cli", "benchmarks": "cli", "verbs": "cli"}


def git(*args: str) -> str:
    return subprocess.run(["git", *args], capture_output=True, text=True, check=True).stdout


def modules(rev: str) -> dict[str, str]:
    """Module name → path of every ciml_learning module at `rev`."""
    out = {}
    for path in git("ls-tree", "-r", "--name-only", rev, PKG).split():
        if path.endswith(".py"):
            name = "ciml_learning." + path[len(PKG):-3].replace("/", ".")
            out[name.removesuffix(".__init__")] = path
    return out


def floor_today(head: dict[str, str]) -> dict[str, str]:
    """Base name → floor in today's layout (HEAD)."""
    return {m.split(".")[-1]: m.split(".")[1] for m in head if m.count(".") >= 2 and m.split(".")[1] in FLOORS}


def floor(module: str, today: dict[str, str]) -> str:
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in FLOORS and (len(parts) > 2 or parts[1] in ("effects", "diagnosis")):
        if parts[1] == "diagnosis" and parts[-1] == "commands":
            return "cli"
        return parts[1]
    base = parts[1] if len(parts) > 1 else "__init__"
    return RENAMED.get(base) or today.get(base, "?")


def imports(source: str, me: str, known: set[str], package: bool) -> list[str]:
    """ciml_learning modules imported anywhere in `source` (relative imports resolved; `package`:
    `me` is a package's __init__, whose `.` is itself)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = me.split(".")
                pkg = parts[: len(parts) - node.level + int(package)]
                base = ".".join([*pkg, base] if base else pkg)
            found += [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
    return [m for m in found if m.startswith("ciml_learning")]


def graph(rev: str, today: dict[str, str]) -> tuple[Counter, list[str]]:
    mods = modules(rev)
    edges: Counter = Counter()
    up = []
    for me, path in mods.items():
        src = git("show", f"{rev}:{path}")
        for target in set(imports(src, me, set(mods), path.endswith("__init__.py"))):
            a, b = floor(me, today), floor(target, today)
            edges[a, b] += 1
            if a in FLOORS and b in FLOORS and FLOORS.index(b) > FLOORS.index(a):
                up.append(f"{me} → {target}")
    return edges, sorted(up)


def main(revs: list[str]) -> None:
    today = floor_today(modules("HEAD"))
    for rev in revs:
        edges, up = graph(rev, today)
        print(f"## {rev} ({git('log', '-1', '--format=%h %ad', '--date=short', rev).strip()}): "
              f"{len(modules(rev))} modules, imports going up a floor: {len(up)}")
        for line in up:
            print(f"- {line}")
        print("\n```mermaid\nflowchart BT")
        for (a, b), n in sorted(edges.items()):
            if a != b and "?" not in (a, b):
                arrow = "-. up .->" if FLOORS.index(b) > FLOORS.index(a) else "-->"
                print(f"  {a} {arrow}|{n}| {b}")
        print("```\n")


if __name__ == "__main__":
    main(sys.argv[1:] or ["HEAD"])
