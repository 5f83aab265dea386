"""`ciml_container`: several CIML nodes composed in one process, spun by one executor.

    ciml_container --node PKG EXEC [--ros-args -r __node:=NAME -p name:=value ...] [--node ...]

Each `--node` starts one node as `ros2 run PKG EXEC <its arguments>` would, with the same
node-local arguments (name, parameters, remaps), but in this process: rclpy executors with
several nodes are the ROS 2 way to compose Python nodes (rclcpp's component containers
have no rclpy counterpart). Composed, the messages between the nodes stay in the process
(Fast DDS delivers them without a transport) and one DirectExecutor serves every node:
measured on the live graph (results/LIVE_GRAPH.md, first session), the CPU of a 250 Hz
cycle was ~18 ms for eight processes, and 2.8 ms for the control container (then with the
model server), 2.0 ms for the learning container and ~1.1 ms for the learner.

A node's class is found by its executable's name in the `ciml.nodes` entry points, which
every package registers for its own nodes, so this module imports no package above it.
`ciml launch` starts containers from a launch file's `containers` argument
(ciml_learning.ros.launch_file.process_plan).
"""
from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points

from ciml_learning.core.errors import CimlError

NODE_GROUP = "ciml.nodes"
"""Entry-point group: executable name → node class (`mujoco_bridge = ciml_sim.bridge_node:MujocoBridge`)."""


class ContainerError(CimlError):
    """A container command line that names no node, an unknown node or a wrong package."""


def node_class(pkg: str, executable: str) -> type:
    """The node class behind `ros2 run PKG EXECUTABLE`."""
    found = [ep for ep in entry_points(group=NODE_GROUP) if ep.name == executable]
    if not found:
        known = sorted(ep.name for ep in entry_points(group=NODE_GROUP))
        raise ContainerError(f"no composable node {executable!r}; installed: {', '.join(known) or 'none'}")
    ep = found[0]
    if ep.value.split(".", 1)[0] != pkg:
        raise ContainerError(f"node {executable!r} belongs to {ep.value.split('.', 1)[0]}, not {pkg}")
    return ep.load()


def parse_command_line(argv: Sequence[str]) -> list[tuple[str, str, list[str]]]:
    """[(pkg, executable, node arguments)] from `--node PKG EXEC args... --node ...`."""
    argv = list(argv)
    nodes: list[tuple[str, str, list[str]]] = []
    i = 0
    while i < len(argv):
        if argv[i] != "--node" or i + 2 >= len(argv):
            raise ContainerError(f"expected --node PKG EXEC at {' '.join(argv[i:i + 3])!r}")
        j = i + 3
        while j < len(argv) and argv[j] != "--node":
            j += 1
        nodes.append((argv[i + 1], argv[i + 2], argv[i + 3:j]))
        i = j
    if not nodes:
        raise ContainerError("usage: ciml_container --node PKG EXEC [ARGS ...] [--node PKG EXEC [ARGS ...] ...]")
    return nodes


def factories(argv: Sequence[str]) -> list[Callable]:
    """One node factory per `--node` (classes resolved before any node starts)."""
    out = []
    for pkg, exe, args in parse_command_line(argv):
        cls = node_class(pkg, exe)

        def make(cls=cls, args=args):
            return cls(cli_args=args)

        make.__name__ = cls.__name__
        out.append(make)
    return out


def main(argv: Sequence[str] | None = None) -> None:
    from ciml_learning.ros.ros_common import run_nodes

    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        made = factories(argv)
    except CimlError as err:
        print(f"ciml_container: error: {err}", file=sys.stderr)
        raise SystemExit(1) from None
    run_nodes(made, args=[], name="ciml_container")


if __name__ == "__main__":
    main()
