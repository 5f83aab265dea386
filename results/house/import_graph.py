"""ciml_learning's import graph by floor at a git revision, for docs/ARCHITECTURE.md §3.

    python results/house/import_graph.py REV [REV ...]

For each revision: every import between ciml_learning modules (module level and inside
functions) counted by (importer's floor → imported module's floor), and the imports that go up
a floor. Before the floors existed (the flat package) a module is placed on the floor its
namesake sits on today (cli.py → cli/main, cliargs → cli/args; learning_commands, commands
and diagnosis/commands → cli, launcher → cli (its verb) as the floors commit moved them), so
the same rule is applied to both layouts. The imports are read by the architecture test's own
walker (test/test_architecture.py `imports_of`: statements anywhere, import and entry-point strings),
given the revision's modules. Prints the imports that go up and a Mermaid graph.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections import Counter

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "test"))
import test_architecture as arch  # noqa: E402  (the floors and the import walker, defined once)

FLOORS = arch.FLOORS
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


def graph(rev: str, today: dict[str, str]) -> tuple[Counter, list[str]]:
    mods = modules(rev)
    edges: Counter = Counter()
    up = []
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "archive", rev, PKG], capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        saved = dict(arch.MODULES)
        arch.MODULES.clear()  # the walker resolves `from m import n` against the revision's modules
        arch.MODULES.update({m: os.path.join(tmp, p) for m, p in mods.items()})
        try:
            for me, path in mods.items():
                for target in {i.target for i in arch.imports_of(os.path.join(tmp, path), me=me)
                               if i.target.startswith("ciml_learning")}:
                    a, b = floor(me, today), floor(target, today)
                    edges[a, b] += 1
                    if a in FLOORS and b in FLOORS and FLOORS.index(b) > FLOORS.index(a):
                        up.append(f"{me} → {target}")
        finally:
            arch.MODULES.clear()
            arch.MODULES.update(saved)
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
