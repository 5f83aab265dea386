"""Argument types of the `ciml` verbs: bad values end in argparse's one-line usage error
(exit 2) before any work starts, never in a traceback later.

- finite(lo, hi): a float in [lo, hi] (NaN and ±inf refused).
- integer(lo, hi): an int in [lo, hi].
- jobs: an integer; cap_jobs() checks it is -1 (all cores) or positive and bounds it by the
  cores this process may use, saying so when it does.
- path: a non-empty path of valid text (no NUL, no undecodable bytes), at most PATH_MAX.

Verb: what a package registers for each of its verbs (entry point group `ciml.verbs`).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

PATH_MAX = 4096


def finite(lo: float = -math.inf, hi: float = math.inf, unit: str = "") -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(x) or not lo <= x <= hi:
            raise argparse.ArgumentTypeError(f"expected a finite number in [{lo:g}, {hi:g}]{unit}, got {text!r}")
        return x

    parse.__name__ = "number"
    return parse


def integer(lo: int, hi: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            x = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= x <= hi:
            raise argparse.ArgumentTypeError(f"expected an integer in [{lo}, {hi}], got {text!r}")
        return x

    parse.__name__ = "integer"
    return parse


def jobs(text: str) -> int:
    """An integer; cap_jobs() checks the range (-1 or positive) when the verb runs."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected -1 or a positive integer, got {text!r}") from None


def available_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def cap_jobs(n: int, what: str = "--jobs") -> int:
    """n processes bounded by the available cores (-1: all of them); a note on stderr when capped."""
    if n == 0 or n < -1:
        from ciml_learning.core.errors import CimlError

        raise CimlError(f"{what} must be a positive number of processes or -1 (all cores), got {n}")
    cores = available_cores()
    if n == -1:
        return cores
    if n > cores:
        print(f"ciml: note: {what} {n} capped at the {cores} available cores", file=sys.stderr)
        return cores
    return n


def path(text: str) -> str:
    """A path argument: non-empty text that the file system and our messages can carry."""
    if not text:
        raise argparse.ArgumentTypeError("expected a path, got an empty string")
    if "\x00" in text:
        raise argparse.ArgumentTypeError("a path cannot contain a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise argparse.ArgumentTypeError(f"path {text.encode('utf-8', 'surrogateescape')!r} is not valid "
                                         "UTF-8 text") from None
    if len(text.encode("utf-8")) > PATH_MAX:
        raise argparse.ArgumentTypeError(f"path longer than {PATH_MAX} bytes")
    return text


def cluster_address(text: str) -> str:
    """A --cluster value (cluster.parse_cluster: local:N or a Dask scheduler's HOST:PORT), imported when
    first parsed so that building the parser imports none of the engine."""
    from ciml_learning.learning.cluster import parse_cluster

    return parse_cluster(text)


class RegistryNames:
    """argparse `choices` read from a registry (a dict of names) when first needed, so that
    building the parser imports none of the library (the learners' registry imports numba)."""

    def __init__(self, module: str, attribute: str) -> None:
        self.module, self.attribute = module, attribute

    def _names(self) -> list[str]:
        import importlib

        return sorted(getattr(importlib.import_module(self.module), self.attribute))

    def __contains__(self, name: object) -> bool:
        return name in self._names()

    def __iter__(self):
        return iter(self._names())


def assignment(text: str) -> tuple[str, str]:
    """NAME=VALUE (a benchmark option): (name, value)."""
    name, sep, value = text.partition("=")
    if not sep or not name.isidentifier() or not value:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name, value


path.__name__ = "path"
assignment.__name__ = "NAME=VALUE"
jobs.__name__ = "jobs"


@dataclass(frozen=True)
class Verb:
    """One `ciml` verb. The package that implements it registers it in its setup.py as an entry
    point of the group `ciml.verbs` (name: the verb; value: "package.module:OBJECT", this object),
    as ros2cli's verbs are; `ciml` lists the verbs of the packages installed, so a package
    installed alone brings its own verbs and never needs a package above it."""

    help: str
    """one line in `ciml --help`"""
    arguments: Callable[[argparse.ArgumentParser], None]
    """adds the verb's own options to its parser (--robot/--urdf/--feet are added by `ciml`)"""
    run: str
    """"package.module:function" taking the parsed arguments and returning the exit code; imported
    only when the verb runs (keeps `ciml --help` fast); in the registering package"""
    epilog: str = ""
    """help text after the options: paragraphs (wrapped) and `example:` lines (kept whole)"""
    order: int = 1000
    """place in `ciml --help` (lower first; ties by name)"""
    no_robot: str = ""
    """why the verb takes no robot: `ciml` then refuses --robot, --urdf and --feet with this reason
    in one line (exit 1) rather than ignore them; empty: the verb reads them (cli.profile_from_args)"""


class OneLineParser(argparse.ArgumentParser):
    """argparse with its usage error on one line (exit 2); `--help` still shows the usage.
    Subparsers inherit the class."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, one_line(f"{self.prog}: error: {message} (see {self.prog} --help)") + "\n")


def one_line(text: str, limit: int = 2000) -> str:
    """A message as one printable line: first line only, whitespace collapsed, bytes that
    are not UTF-8 (surrogate-escaped paths) shown as escapes, at most `limit` characters."""
    first = text.splitlines()[0] if text.strip() else text
    first = " ".join(first.split())
    return first.encode("utf-8", "backslashreplace").decode("utf-8")[:limit]
