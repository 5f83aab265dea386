"""Files in and out: every output complete-new or complete-old, every input bounded.

Outputs (docs/ARCHITECTURE.md, "Files: atomic outputs and checks"):

- atomic_write_bytes/_text/_json (atomic_write_stream: content written by a function, with
  no copy of it in memory): one file, written to a temporary sibling (`.NAME.tmp-PID`),
  fsynced, renamed over NAME, then the folder fsynced.
- atomic_dir: a whole output directory (model, diagnosis, snapshot) built under a
  temporary sibling with its final file names, every file fsynced, then published with
  one rename; an existing directory is swapped with renameat2(RENAME_EXCHANGE), so a
  reader always finds the complete old or the complete new one (where the file system
  cannot exchange: old → `.NAME.old-PID`, new → NAME — a kill between leaves NAME absent,
  never mixed).
- Temporaries of dead processes (`.NAME.tmp-PID`, `.NAME.old-PID`, `.NAME.partial-PID`)
  are removed by the next write of NAME.
- check_out_file/check_out_dir: `--out` may replace only a regular file, an empty folder
  or a folder this kind of output created (recognised by its own description file) —
  never a device node, a symlink, or someone else's folder.

Inputs: load_json_bounded and load_yaml_bounded refuse files over a size limit, JSON nested
deeper than a limit and YAML whose aliases expand beyond a node limit (alias bombs).

Test hook: with CIML_FAULT_AT=N (or NAME:N) in the environment, the process ends with
os._exit(137) — as under kill -9 — just before the N-th fault point (of that NAME:
write, fsync, rename, exchange, dirsync, cleanup); test/test_fault_injection.py uses it
to check the old-or-new-or-absent promise at every step.
"""
from __future__ import annotations

import ctypes
import errno
import json
import os
import re
import shutil
import stat
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, BinaryIO

from ciml_learning.core.errors import CimlError

FAULT_ENV = "CIML_FAULT_AT"
_fault_counts: dict[str, int] = {}


class OutputError(CimlError):
    """An output path cannot be (re)placed safely."""


class InputFileError(CimlError):
    """An input file is too large, too deeply nested or not what it claims to be."""


def fault_point(step: str) -> None:
    """Test hook (module docstring): end the process as kill -9 would before this step."""
    spec = os.environ.get(FAULT_ENV)
    if not spec:
        return
    _fault_counts[""] = _fault_counts.get("", 0) + 1
    _fault_counts[step] = _fault_counts.get(step, 0) + 1
    name, _, n = spec.rpartition(":")
    try:
        hit = _fault_counts[name] == int(n) if name else _fault_counts[""] == int(n)
    except (KeyError, ValueError):
        return
    if hit:
        os._exit(137)


# ---------------------------------------------------------------------- low-level steps
def fsync_dir(path: str) -> None:
    """Make a rename in `path` durable (a directory's entries are data too)."""
    fault_point("dirsync")
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_file(path: str, write: Callable[[BinaryIO], object]) -> None:
    fault_point("write")
    with open(path, "xb") as f:
        write(f)
        f.flush()
        fault_point("fsync")
        os.fsync(f.fileno())


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: str, b: str) -> bool:
    """Swap two paths in one step (Linux renameat2); False where the system cannot."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    fault_point("exchange")
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV):
        return False
    raise OSError(err, os.strerror(err), b)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale(path: str, name_pattern: str | None = None) -> None:
    """Remove temporaries of NAME left by dead processes (`.NAME.{tmp,old,partial}-PID`);
    with `name_pattern` (a regular expression), of every NAME of `path`'s folder matching it."""
    parent, name = os.path.split(os.path.abspath(path))
    if name_pattern is not None:
        parent = os.path.abspath(path)
    pattern = re.compile(rf"\.(?:{name_pattern or re.escape(name)})\.(?:tmp|old|partial)-(\d+)")
    try:
        entries = os.listdir(parent)
    except OSError:
        return
    for entry in entries:
        m = pattern.fullmatch(entry)
        if not m or int(m.group(1)) == os.getpid() or _pid_alive(int(m.group(1))):
            continue
        p = os.path.join(parent, entry)
        fault_point("cleanup")
        if os.path.isdir(p) and not os.path.islink(p):
            shutil.rmtree(p, ignore_errors=True)
        else:
            try:
                os.unlink(p)
            except OSError:
                pass


def temp_sibling(path: str, tag: str = "tmp") -> str:
    parent, name = os.path.split(os.path.abspath(path))
    return os.path.join(parent, f".{name}.{tag}-{os.getpid()}")


# ---------------------------------------------------------------------- safe --out
def _describe(mode: int) -> str:
    for test, what in ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a named pipe"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"), (stat.S_ISREG, "a file")):
        if test(mode):
            return what
    return "a special file"


def check_out_parent(path: str, what: str) -> str:
    if not path or "\x00" in path:
        raise OutputError(f"{what}: empty or invalid path {path!r}")
    full = os.path.abspath(path)
    parent = os.path.dirname(full)
    probe = parent
    while not os.path.lexists(probe):  # the first existing ancestor must be a writable folder
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        raise OutputError(f"{what} {path}: {probe} is not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {path}: {probe} is not writable")
    return full


def _makedirs(parent: str, what: str, path: str) -> None:
    try:
        os.makedirs(parent, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{what} {path}: cannot create {parent} ({err.strerror or err})") from None


def _lstat(full: str, path: str, what: str) -> os.stat_result | None:
    """lstat of an --out path; None when it does not exist; other errors as one OutputError line."""
    try:
        return os.lstat(full)
    except FileNotFoundError:
        return None
    except OSError as err:
        raise OutputError(f"{what} {path}: {err.strerror or err}") from None


def check_out_file(path: str, what: str = "--out") -> str:
    """`path` may be written as a file: absent or a regular file (never a device, link or folder)."""
    full = check_out_parent(path, what)
    st = _lstat(full, path, what)
    if st is None:
        return full
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(f"{what} {path} is {_describe(st.st_mode)}; refusing to replace it (give a file path)")
    return full


def check_out_dir(path: str, is_ours: Callable[[str], bool], kind: str, what: str = "--out") -> str:
    """`path` may be (re)placed as a `kind` directory: absent, empty, or one `is_ours` recognises."""
    full = check_out_parent(path, what)
    st = _lstat(full, path, what)
    if st is None:
        return full
    if not stat.S_ISDIR(st.st_mode):
        raise OutputError(f"{what} {path} is {_describe(st.st_mode)}, not a {kind} directory; refusing to replace it")
    try:
        empty = not os.listdir(full)
    except OSError as err:
        raise OutputError(f"{what} {path}: {err.strerror or err}") from None
    if not empty and not is_ours(full):
        raise OutputError(f"{what} {path} is a directory that is not a CIML {kind}; refusing to replace it "
                          "(give a new or empty directory)")
    return full


# ---------------------------------------------------------------------- atomic writes
def atomic_write_bytes(path: str, data: bytes, what: str = "--out") -> None:
    """Write to `.NAME.tmp-PID` beside `path`, fsync, rename over `path`, fsync the folder."""
    atomic_write_stream(path, lambda f: f.write(data), what)


def atomic_write_stream(path: str, write: Callable[[BinaryIO], object], what: str = "--out") -> None:
    """atomic_write_bytes of what write(file) writes to the (binary, seekable) file."""
    full = check_out_file(path, what)
    parent = os.path.dirname(full)
    _makedirs(parent, what, path)
    clean_stale(full)
    tmp = temp_sibling(full)
    try:
        if os.path.lexists(tmp):
            os.unlink(tmp)
        _write_file(tmp, write)
        fault_point("rename")
        os.replace(tmp, full)
        fsync_dir(parent)
    except OSError as err:
        raise OutputError(f"cannot write {path}: {err.strerror or err}") from None
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


def atomic_write_text(path: str, text: str, what: str = "--out") -> None:
    atomic_write_bytes(path, text.encode("utf-8"), what)


def json_dumps(obj: Any) -> str:
    return json.dumps(obj, indent=2, sort_keys=False, allow_nan=False) + "\n"


def atomic_write_json(path: str, obj: Any, what: str = "--out") -> None:
    atomic_write_text(path, json_dumps(obj), what)


@contextmanager
def atomic_dir(path: str, is_ours: Callable[[str], bool], kind: str, what: str = "--out",
               copy_from_old: bool = False) -> Iterator[str]:
    """Build a directory under a temporary sibling, then publish it at `path` in one step.

    Yields the temporary folder; write the final file names into it (plain writes: this
    fsyncs them). On success the folder replaces `path` (module docstring); on an exception
    it is removed and `path` is untouched. With copy_from_old, the temporary folder starts
    as a copy of the existing directory (to rewrite some of its files).
    """
    full = check_out_dir(path, is_ours, kind, what)
    parent = os.path.dirname(full)
    _makedirs(parent, what, path)
    clean_stale(full)
    tmp = temp_sibling(full)
    try:
        if os.path.lexists(tmp):
            shutil.rmtree(tmp)
        if copy_from_old and os.path.isdir(full):
            shutil.copytree(full, tmp, symlinks=True)
        else:
            os.mkdir(tmp)
    except OSError as err:
        raise OutputError(f"{what} {path}: cannot create {tmp} ({err.strerror or err})") from None
    ok = False
    try:
        yield tmp
        publish_dir(tmp, full, what)
        ok = True
    finally:
        if not ok:
            shutil.rmtree(tmp, ignore_errors=True)


def fsync_tree(root: str) -> None:
    for d, _, files in os.walk(root):
        for name in files:
            p = os.path.join(d, name)
            if os.path.islink(p):
                continue
            fault_point("fsync")
            fd = os.open(p, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        fsync_dir(d)


def publish_dir(tmp: str, full: str, what: str = "--out") -> None:
    """Publish the complete folder `tmp` at `full` (replacing an existing directory in one step)."""
    parent = os.path.dirname(full)
    try:
        fsync_tree(tmp)
        if os.path.isdir(full) and not os.path.islink(full):
            if _exchange(tmp, full):  # tmp now holds the old directory
                fsync_dir(parent)
                fault_point("cleanup")
                shutil.rmtree(tmp, ignore_errors=True)
                return
            old = temp_sibling(full, "old")
            fault_point("rename")
            os.rename(full, old)
            fault_point("rename")
            os.rename(tmp, full)
            fsync_dir(parent)
            fault_point("cleanup")
            shutil.rmtree(old, ignore_errors=True)
            return
        fault_point("rename")
        os.rename(tmp, full)
        fsync_dir(parent)
    except OSError as err:
        raise OutputError(f"{what} {full}: cannot publish ({err.strerror or err})") from None


# ---------------------------------------------------------------------- bounded inputs
JSON_MAX_BYTES = 64 * 2**20
JSON_MAX_DEPTH = 64
YAML_MAX_BYTES = 2**20
YAML_MAX_NODES = 100_000


def _depth(obj: Any, limit: int) -> int:
    """Nesting depth of a loaded JSON value (iterative: no recursion limit)."""
    deepest, stack = 0, [(obj, 1)]
    while stack:
        x, d = stack.pop()
        deepest = max(deepest, d)
        if deepest > limit:
            break
        if isinstance(x, dict):
            stack.extend((v, d + 1) for v in x.values())
        elif isinstance(x, list):
            stack.extend((v, d + 1) for v in x)
    return deepest


def read_bounded(path: str, max_bytes: int, what: str) -> bytes:
    """The bytes of a regular file of at most max_bytes; InputFileError (one line) otherwise."""
    try:
        with open(path, "rb") as f:
            st = os.fstat(f.fileno())
            if not stat.S_ISREG(st.st_mode):
                raise InputFileError(f"{what} {path} is {_describe(st.st_mode)}, not a file")
            data = f.read(max_bytes + 1)
    except FileNotFoundError:
        raise InputFileError(f"{what} not found: {path}") from None
    except IsADirectoryError:
        raise InputFileError(f"{what} {path} is a directory, not a file") from None
    except OSError as err:
        raise InputFileError(f"cannot read {what} {path}: {err.strerror or err}") from None
    if len(data) > max_bytes:
        raise InputFileError(f"{what} {path} is larger than {max_bytes} bytes; refusing to read it")
    return data


def loads_json_bounded(text: str | bytes, where: str, max_depth: int = JSON_MAX_DEPTH) -> Any:
    try:
        obj = json.loads(text)
    except RecursionError:
        raise InputFileError(f"{where} is nested deeper than {max_depth} levels") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputFileError(f"{where} is not valid JSON (truncated or corrupt: {err})") from None
    if _depth(obj, max_depth) > max_depth:
        raise InputFileError(f"{where} is nested deeper than {max_depth} levels")
    return obj


def load_json_bounded(path: str, what: str = "JSON file", max_bytes: int = JSON_MAX_BYTES,
                      max_depth: int = JSON_MAX_DEPTH) -> Any:
    """A JSON file with size and depth limits; InputFileError (one line) for anything else."""
    return loads_json_bounded(read_bounded(path, max_bytes, what), f"{what} {path}", max_depth)


def load_yaml_bounded(path: str, what: str = "YAML file", max_bytes: int = YAML_MAX_BYTES,
                      max_nodes: int = YAML_MAX_NODES, yaml_errors: bool = False) -> Any:
    """A YAML file (safe types only) with a size limit and a limit on the nodes its aliases
    expand to, counted on the composed graph before anything is built (alias bombs);
    InputFileError (one line) for anything else, invalid YAML included (with yaml_errors:
    yaml.YAMLError passes through, for callers that word it themselves)."""
    import yaml

    data = read_bounded(path, max_bytes, what)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputFileError(f"{what} {path} is not UTF-8 text ({err.reason} at byte {err.start})") from None

    class BoundedLoader(yaml.SafeLoader):
        def compose_document(self):  # type: ignore[no-untyped-def]
            node = super().compose_document()
            _count_nodes(node, max_nodes, f"{what} {path}")
            return node

    try:
        return yaml.load(text, Loader=BoundedLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as err:
        if yaml_errors:
            raise
        msg = " ".join(str(err).split())
        raise InputFileError(f"{what} {path}: invalid YAML ({msg[:300]})") from None
    except RecursionError:
        raise InputFileError(f"{what} {path} is nested too deeply") from None


def _count_nodes(root: Any, limit: int, where: str) -> None:
    """Nodes of a composed YAML graph as the loaded value will hold them (an alias counts as
    the whole node it repeats), memoised per node: a bomb is measured, never expanded."""
    import yaml

    size: dict[int, int] = {}
    stack: list[tuple[Any, bool]] = [(root, False)]
    on_path: set[int] = set()
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            children = _children(node, yaml)
            total = 1 + sum(size[id(c)] for c in children)
            size[key] = total
            if total > limit:
                raise InputFileError(f"{where}: expands to more than {limit} YAML nodes (aliases); refusing it")
            continue
        if key in size:
            continue
        if key in on_path:  # a recursive alias
            raise InputFileError(f"{where}: a recursive YAML alias; refusing it")
        on_path.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node, yaml) if id(c) not in size)


def _children(node: Any, yaml: Any) -> list[Any]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [x for kv in node.value for x in kv]
    return []
