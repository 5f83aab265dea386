"""The subset of the ROS 2 YAML launch format that CIML's launch files use (docs/LIVE_GRAPH.md).

No `launch` wheel exists for this platform, so `ciml launch` reads the same file that
`ros2 launch` reads on a full install. Supported, with ros2 launch's meaning:

- `arg` (name, default, description): a launch argument, set as `name:=value`;
- `let` (name, value): a launch configuration computed in the file;
- `set_env` (name, value): an environment variable of every process started after it
  (here: before the first node, so that it holds for all of them);
- `node` (pkg, exec, name, namespace, param [name/value or from], remap [from/to],
  env [name/value: this node's process only, over `set_env`], ros_args, args, launch-prefix,
  `if`/`unless`; `output` is accepted, output always goes to the screen and, with --log-dir,
  to a file): one process;
- substitutions `$(var NAME)`, `$(find-pkg-share PKG)`, `$(env NAME [DEFAULT])`,
  `$(dirname)` and `$(filename)`; conditions are "true"/"false" (or 1/0), as in launch.

Anything else (include, group, executable, other substitutions) is refused with a
one-line LaunchFileError naming it, never ignored. Parameter values are typed as
launch_ros types them: the substituted text read as a YAML scalar ("250.0" → float,
"true" → bool, "" → string). This module only parses and resolves; processes are
started by ciml_learning.ros.launcher.
"""
from __future__ import annotations

import os
import re
import shlex
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import yaml

from ciml_learning.core.errors import CimlError


class LaunchFileError(CimlError):
    """A launch file or a launch argument that cannot be used."""


@dataclass(frozen=True)
class LaunchArg:
    name: str
    default: str | None
    description: str = ""


@dataclass(frozen=True)
class NodeAction:
    """One node to start, every substitution resolved."""

    pkg: str
    executable: str
    name: str | None = None
    namespace: str | None = None
    parameters: tuple[tuple[str, object], ...] = ()
    param_files: tuple[str, ...] = ()
    remaps: tuple[tuple[str, str], ...] = ()
    extra_ros_args: tuple[str, ...] = ()
    args: tuple[str, ...] = ()
    launch_prefix: tuple[str, ...] = ()
    """Words before the executable (`launch-prefix`, e.g. `nice -n 10`), as launch_ros runs them."""
    environment: tuple[tuple[str, str], ...] = ()
    """The node's own `env` entries, set over the file's `set_env` for its process only."""

    @property
    def label(self) -> str:
        return self.name or self.executable

    def ros_arguments(self) -> list[str]:
        """Command-line arguments after the executable (`--ros-args -r __node:=… -p name:=value`)."""
        out = list(self.args)
        ros: list[str] = []
        if self.name:
            ros += ["-r", f"__node:={self.name}"]
        if self.namespace:
            ros += ["-r", f"__ns:={self.namespace if self.namespace.startswith('/') else '/' + self.namespace}"]
        for path in self.param_files:
            ros += ["--params-file", path]
        for key, value in self.parameters:
            ros += ["-p", f"{key}:={parameter_text(value)}"]
        for src, dst in self.remaps:
            ros += ["-r", f"{src}:={dst}"]
        ros += list(self.extra_ros_args)
        return out + (["--ros-args", *ros] if ros else [])


@dataclass(frozen=True)
class ProcessAction:
    """One process `ciml launch` starts: a node on its own, or a container of nodes."""

    label: str
    nodes: tuple[NodeAction, ...]

    @property
    def composed(self) -> bool:
        return len(self.nodes) != 1 or self.nodes[0].label != self.label

    @property
    def environment(self) -> dict[str, str]:
        """The nodes' own `env` (process_plan checks that a container's nodes agree)."""
        return dict(self.nodes[0].environment)


CONTAINERS_ARG = "containers"
"""The launch argument `ciml launch` reads for composition: groups `NAME:node,node,...`
separated by spaces; each group's nodes run in one process (ciml_container, one executor),
the nodes of no group each in its own. `ros2 launch` ignores it and starts each node as
its own process: launch_ros composes rclcpp components only."""


def process_plan(desc: LaunchDescription) -> list[ProcessAction]:
    """The processes of a launch description: its `containers` groups, then lone nodes, in file order."""
    by_label = {n.label: n for n in desc.nodes}
    spec = desc.configuration.get(CONTAINERS_ARG, "").split()
    groups: list[ProcessAction] = []
    placed: dict[str, str] = {}
    for item in spec:
        name, sep, members = item.partition(":")
        names = [m for m in members.split(",") if m]
        if not sep or not name or not names:
            raise LaunchFileError(f"{CONTAINERS_ARG}: {item!r} is not NAME:node,node,...")
        for m in names:
            if m in placed:
                raise LaunchFileError(f"{CONTAINERS_ARG}: node {m!r} is in both {placed[m]} and {name}")
            placed[m] = name
        started = tuple(by_label[m] for m in names if m in by_label)  # a node switched off by `if` is skipped
        prefixes = {n.launch_prefix for n in started}
        if len(prefixes) > 1:
            shown = " / ".join(" ".join(p) or "none" for p in sorted(prefixes))
            raise LaunchFileError(f"{CONTAINERS_ARG}: the nodes of {name} have different launch-prefix ({shown}); "
                                  "one process has one")
        environments = {tuple(sorted(n.environment)) for n in started}
        if len(environments) > 1:
            shown = " / ".join(" ".join(f"{k}={v}" for k, v in e) or "none" for e in sorted(environments))
            raise LaunchFileError(f"{CONTAINERS_ARG}: the nodes of {name} have different env ({shown}); "
                                  "one process has one")
        if started:
            groups.append(ProcessAction(name, started))
    unknown = sorted(m for m in placed if m not in desc.declared_nodes)
    if unknown:
        raise LaunchFileError(f"{CONTAINERS_ARG}: no node named {', '.join(unknown)} in {os.path.basename(desc.path)}")
    return groups + [ProcessAction(n.label, (n,)) for n in desc.nodes if n.label not in placed]


@dataclass
class LaunchDescription:
    path: str
    arguments: list[LaunchArg] = field(default_factory=list)
    nodes: list[NodeAction] = field(default_factory=list)
    configuration: dict[str, str] = field(default_factory=dict)
    declared_nodes: set[str] = field(default_factory=set)
    """Every node entry's name, started or switched off by its condition."""
    environment: dict[str, str] = field(default_factory=dict)
    """`set_env` variables, set for every process the file starts."""


_SUBST = re.compile(r"\$\(([^()]*)\)")


def parameter_value(text: str) -> object:
    """A parameter value as launch_ros types it: the text read as one YAML scalar or list."""
    if text == "":
        return ""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if value is None or isinstance(value, dict):
        return text  # 'null', '~' or a mapping are not parameter values: keep the text
    return value


def parameter_text(value: object) -> str:
    """The `-p name:=…` text that rcl reads back as `value` (YAML, one line)."""
    if isinstance(value, str) and value and "\n" not in value:
        try:
            if yaml.safe_load(value) == value:
                return value  # plain text YAML reads back unchanged: no quotes
        except yaml.YAMLError:
            pass
    return yaml.safe_dump(value, default_flow_style=True, width=1 << 16).strip().removesuffix("...").strip()


def truthy(text: str, where: str) -> bool:
    """launch's condition rule: 'true'/'1' → True, 'false'/'0' → False, anything else is an error."""
    t = text.strip().lower()
    if t in ("true", "1"):
        return True
    if t in ("false", "0"):
        return False
    raise LaunchFileError(f"{where}: condition {text!r} is neither true nor false")


def find_package_share(pkg: str) -> str:
    """`$(find-pkg-share PKG)` through the ament index (AMENT_PREFIX_PATH; the venv prefix if unset)."""
    return os.path.join(find_package_prefix(pkg), "share", pkg)


def find_package_prefix(pkg: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    _default_ament_prefix()
    try:
        return get_package_prefix(pkg)
    except (PackageNotFoundError, ValueError) as err:  # ValueError: not a package name
        raise LaunchFileError(f"package {pkg!r} not found in the ament index "
                              f"(AMENT_PREFIX_PATH={os.environ.get('AMENT_PREFIX_PATH', '')})") from err


def find_executable(pkg: str, executable: str) -> str:
    """<prefix>/lib/<pkg>/<executable>, where `ros2 run` looks."""
    path = os.path.join(find_package_prefix(pkg), "lib", pkg, executable)
    if not (os.path.isfile(path) and os.access(path, os.X_OK)):
        raise LaunchFileError(f"executable {executable!r} not found in package {pkg!r} ({path})")
    return path


def _default_ament_prefix() -> None:
    """Without a sourced setup script, this interpreter's prefix (the venv) is the ament prefix."""
    import sys

    if not os.environ.get("AMENT_PREFIX_PATH"):
        os.environ["AMENT_PREFIX_PATH"] = sys.prefix


class _Resolver:
    def __init__(self, path: str, config: dict[str, str], find_share: Callable[[str], str]) -> None:
        self.path = path
        self.config = config
        self.find_share = find_share

    def __call__(self, value: object, where: str) -> str:
        if isinstance(value, bool):
            return "true" if value else "false"
        if isinstance(value, (int, float)):
            return str(value)
        if not isinstance(value, str):
            raise LaunchFileError(f"{where}: expected a text value, got {type(value).__name__}")
        return _SUBST.sub(lambda m: self._one(m.group(1), where), value)

    def _one(self, body: str, where: str) -> str:
        parts = body.split()
        if not parts:
            raise LaunchFileError(f"{where}: empty substitution $()")
        kind, rest = parts[0], parts[1:]
        if kind == "var" and len(rest) == 1:
            if rest[0] not in self.config:
                raise LaunchFileError(f"{where}: launch configuration {rest[0]!r} is not set")
            return self.config[rest[0]]
        if kind == "find-pkg-share" and len(rest) == 1:
            return self.find_share(rest[0])
        if kind == "env" and len(rest) in (1, 2):
            value = os.environ.get(rest[0], rest[1] if len(rest) == 2 else None)
            if value is None:
                raise LaunchFileError(f"{where}: environment variable {rest[0]!r} is not set (no default given)")
            return value
        if kind == "dirname" and not rest:
            return os.path.dirname(os.path.abspath(self.path))
        if kind == "filename" and not rest:
            return os.path.basename(self.path)
        raise LaunchFileError(f"{where}: unsupported substitution $({body}); supported: "
                              "var, find-pkg-share, env, dirname, filename")


_NODE_KEYS = {"pkg", "exec", "name", "namespace", "param", "remap", "env", "ros_args", "args", "if", "unless",
              "output", "launch-prefix"}


def parse_arguments(items: Sequence[str]) -> dict[str, str]:
    """`name:=value` command-line launch arguments."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise LaunchFileError(f"launch argument {item!r} is not of the form name:=value")
        out[name] = value
    return out


def load(path: str, arguments: Mapping[str, str] | None = None,
         find_share: Callable[[str], str] = find_package_share) -> LaunchDescription:
    """Read a YAML launch file and resolve it with `arguments` (name → text).

    Unknown argument names, missing required arguments, unsupported actions or
    substitutions and malformed entries raise LaunchFileError.
    """
    from ciml_learning.core.fileio import InputFileError, load_yaml_bounded

    try:  # size and alias-expansion limits
        doc = load_yaml_bounded(path, "launch file", yaml_errors=True)
    except InputFileError as err:
        raise LaunchFileError(str(err)) from None
    except OSError as err:
        raise LaunchFileError(f"cannot read launch file {path}: {err.strerror}") from err
    except yaml.YAMLError as err:
        raise LaunchFileError(f"{path}: not valid YAML ({' '.join(str(err).split())})") from err
    if not isinstance(doc, dict) or not isinstance(doc.get("launch"), list):
        raise LaunchFileError(f"{path}: not a YAML launch file (expected a top-level 'launch:' list)")
    arguments = dict(arguments or {})
    desc = LaunchDescription(path=path, configuration={})
    resolve = _Resolver(path, desc.configuration, find_share)
    entries = doc["launch"]
    declared = {e["arg"].get("name") for e in entries
                if isinstance(e, dict) and isinstance(e.get("arg"), dict)}
    unknown = sorted(set(arguments) - declared)
    if unknown:
        raise LaunchFileError(f"unknown launch argument(s) {', '.join(unknown)}; "
                              f"this file declares: {', '.join(sorted(n for n in declared if n))}")
    for i, entry in enumerate(entries):
        where = f"{os.path.basename(path)}: entry {i + 1}"
        if not isinstance(entry, dict) or len(entry) != 1:
            raise LaunchFileError(f"{where}: expected one action (arg, let, set_env or node)")
        (kind, body), = entry.items()
        if not isinstance(body, dict):
            raise LaunchFileError(f"{where}: {kind} must be a mapping")
        where = f"{where} ({kind} {body.get('name', body.get('exec', ''))})".rstrip()
        if kind == "arg":
            _arg(desc, body, arguments, resolve, where)
        elif kind == "let":
            _require(body, ("name", "value"), where)
            desc.configuration[str(body["name"])] = resolve(body["value"], where)
        elif kind == "set_env":
            _require(body, ("name", "value"), where)
            if desc.declared_nodes:  # launch sets it for the actions after it only
                raise LaunchFileError(f"{where}: set_env after a node is not supported; put it before the nodes")
            desc.environment[str(body["name"])] = resolve(body["value"], where)
        elif kind == "node":
            node = _node(body, resolve, where)
            desc.declared_nodes.add(resolve(body.get("name", body["exec"]), where))
            if node is not None:
                desc.nodes.append(node)
        else:
            raise LaunchFileError(f"{where}: unsupported action {kind!r}; supported: arg, let, set_env, node")
    return desc


def _require(body: dict, keys: Sequence[str], where: str) -> None:
    missing = [k for k in keys if k not in body]
    if missing:
        raise LaunchFileError(f"{where}: missing {', '.join(missing)}")


def _arg(desc: LaunchDescription, body: dict, arguments: Mapping[str, str], resolve: _Resolver, where: str) -> None:
    _require(body, ("name",), where)
    name = str(body["name"])
    default = body.get("default")
    desc.arguments.append(LaunchArg(name, None if default is None else str(default), str(body.get("description", ""))))
    if name in arguments:
        desc.configuration[name] = arguments[name]
    elif default is not None:
        desc.configuration[name] = resolve(default, where)
    else:
        raise LaunchFileError(f"launch argument {name!r} is required (no default); pass {name}:=VALUE")


def _condition(body: dict, resolve: _Resolver, where: str) -> bool:
    if "if" in body and not truthy(resolve(body["if"], where), where):
        return False
    if "unless" in body and truthy(resolve(body["unless"], where), where):
        return False
    return True


def _pairs(body: dict, key: str, fields: tuple[str, str], resolve: _Resolver, where: str) -> list[tuple[str, str]]:
    """A node's list of two-field mappings (`remap` from/to, `env` name/value), resolved."""
    out = []
    for item in body.get(key, None) or []:
        if not isinstance(item, dict):
            raise LaunchFileError(f"{where}: each {key} is a mapping with {'/'.join(fields)}")
        _require(item, fields, where)
        out.append((resolve(item[fields[0]], where), resolve(item[fields[1]], where)))
    return out


def _node(body: dict, resolve: _Resolver, where: str) -> NodeAction | None:
    unknown = sorted(set(body) - _NODE_KEYS)
    if unknown:
        raise LaunchFileError(f"{where}: unsupported node attribute(s) {', '.join(unknown)}")
    _require(body, ("pkg", "exec"), where)
    if not _condition(body, resolve, where):
        return None
    params: list[tuple[str, object]] = []
    files: list[str] = []
    for p in body.get("param", None) or []:
        if not isinstance(p, dict):
            raise LaunchFileError(f"{where}: each param is a mapping (name/value or from)")
        if "from" in p:
            files.append(resolve(p["from"], where))
            continue
        _require(p, ("name", "value"), where)
        params.append((str(p["name"]), parameter_value(resolve(p["value"], where))))
    remaps = _pairs(body, "remap", ("from", "to"), resolve, where)
    environment = _pairs(body, "env", ("name", "value"), resolve, where)
    name = resolve(body["name"], where) if "name" in body else None
    namespace = resolve(body["namespace"], where) if "namespace" in body else None
    return NodeAction(pkg=resolve(body["pkg"], where), executable=resolve(body["exec"], where), name=name,
                      namespace=namespace, parameters=tuple(params), param_files=tuple(files), remaps=tuple(remaps),
                      extra_ros_args=tuple(resolve(body.get("ros_args", ""), where).split()),
                      args=tuple(resolve(body.get("args", ""), where).split()),
                      launch_prefix=tuple(shlex.split(resolve(body.get("launch-prefix", ""), where))),
                      environment=tuple(environment))


def describe(desc: LaunchDescription) -> str:
    """The file's arguments (name, default, description), one per line, as `ros2 launch -s` lists them."""
    lines = [f"Arguments of {desc.path} (pass as name:=value):"]
    for a in desc.arguments:
        default = "(required)" if a.default is None else f"(default: {a.default!r})"
        lines.append(f"    {a.name}: {a.description} {default}")
    return "\n".join(lines)
