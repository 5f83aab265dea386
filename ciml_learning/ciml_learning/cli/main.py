"""`ciml`: the command line of CIML (docs/ARCHITECTURE.md §4).

Each verb is a thin layer: parse arguments, call the library, write files atomically.
Expected failures (CimlError) print one line and exit 1.

The verbs are registered by the packages that implement them (entry point group `ciml.verbs`,
cliargs.Verb; ciml_learning/cli/verbs.py, ciml_sim/verbs.py), so `ciml` offers the verbs of the
packages installed and this module imports none of them.
"""
from __future__ import annotations

import argparse
import os
import sys
import textwrap
from collections.abc import Callable

from ciml_learning.cli import args as ca
from ciml_learning.core.errors import CimlError

EXIT_ERROR = 1
EXIT_INTERNAL = 70
"""A bug, not bad input (sysexits EX_SOFTWARE): one line, the traceback with CIML_DEBUG=1."""


VERB_GROUP = "ciml.verbs"
"""Entry point group of the verbs (cliargs.Verb): each package registers its own in its setup.py."""


def _run(spec: str) -> Callable[[argparse.Namespace], int]:
    """"package.module:function", imported only when the verb runs (keeps `ciml --help` fast)."""
    module, _, function = spec.partition(":")

    def call(args: argparse.Namespace) -> int:
        import importlib

        return getattr(importlib.import_module(module), function)(args)

    return call


def installed_verbs() -> list[tuple[str, ca.Verb]]:
    """The verbs of the packages installed (entry points of VERB_GROUP), in their order.

    A registration that cannot be loaded costs its verb only: the others still run, and a
    `ciml: note:` line on stderr says what was left out and why."""
    from importlib.metadata import entry_points

    found: dict[str, ca.Verb] = {}
    for ep in entry_points(group=VERB_GROUP):
        try:
            verb = ep.load()
        except Exception as err:  # a broken or half-installed package: its verbs only are missing
            print(ca.one_line(f"ciml: note: verb {ep.name} ({ep.value}) left out: {type(err).__name__}: {err}"),
                  file=sys.stderr)
            continue
        if not isinstance(verb, ca.Verb):
            print(ca.one_line(f"ciml: note: verb {ep.name} ({ep.value}) left out: not a ciml_learning.cli.args.Verb"),
                  file=sys.stderr)
        elif ep.name in found:
            print(ca.one_line(f"ciml: note: verb {ep.name} registered twice; {ep.value} left out"), file=sys.stderr)
        else:
            found[ep.name] = verb
    return sorted(found.items(), key=lambda item: (item[1].order, item[0]))


def _feet(value: str) -> list[str]:
    """--feet 'A,B,C,D' (or A B C D, joined by _join_feet) → names."""
    names = [f.strip() for f in value.split(",") if f.strip()]
    if not names:
        raise argparse.ArgumentTypeError("--feet needs foot frame names, e.g. --feet lf_foot,lh_foot,rf_foot,rh_foot")
    return names


def _global_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """--robot, --urdf, --feet: accepted before and after the verb (after the verb they
    default to SUPPRESS so they do not overwrite what was given before it)."""
    d = {"default": argparse.SUPPRESS} if suppress else {"default": None}
    g = parser.add_argument_group("robot (before or after the verb)")
    g.add_argument("--robot", metavar="PROFILE.yaml", help="robot profile: URDF, feet, joint map, input map, "
                   "or a shipped robot's name (hyq, go1, solo12, a1) (default: HyQ with CIML's own topics; "
                   "docs/ROBOT_PROFILE.md)", **d)
    g.add_argument("--urdf", help="robot URDF, a path or erd:<path in example-robot-data's robots/> "
                   "(shortcut: overrides the profile's urdf)", **d)
    g.add_argument("--feet", type=_feet, metavar="A,B,C,D",
                   help="foot frame names of the URDF, comma-separated or space-separated "
                   "(overrides the profile's feet)", **d)


def _join_feet(argv: list[str], verbs: set[str]) -> list[str]:
    """`--feet A B C D` → `--feet=A,B,C,D`, so the names never swallow the verb."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--feet":
            j = i + 1
            while j < len(argv) and not argv[j].startswith("-") and argv[j] not in verbs:
                j += 1
            out.append("--feet=" + ",".join(argv[i + 1:j]) if j > i + 1 else argv[i])
            i = j
        else:
            out.append(argv[i])
            i += 1
    return out


class _Version(argparse.Action):
    """--version, with the commit looked up only when asked for (it runs git)."""

    def __init__(self, option_strings, dest, **kwargs) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from ciml_learning.core.version import version_text

        print(version_text())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    p = ca.OneLineParser(
        prog="ciml",
        description="Contact-invariant model learning for legged robots: learn a robot's model "
        "error from sensor logs, control with it, and diagnose the sim-to-real gap.",
    )
    _global_options(p, suppress=False)
    p.add_argument("--version", action=_Version, help="the package version and the commit it runs from, then exit")
    sub = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    parent = ca.OneLineParser(add_help=False)
    _global_options(parent, suppress=True)

    for name, v in installed_verbs():
        # paragraphs wrapped here, example lines kept whole (RawDescription keeps them as given)
        epilog = "\n".join(textwrap.fill(par, 100, break_on_hyphens=False) if not par.startswith("example:")
                            else par for par in v.epilog.split("\n")) or None
        s = sub.add_parser(name, parents=[parent], epilog=epilog, formatter_class=argparse.RawDescriptionHelpFormatter,
                           help=v.help)
        v.arguments(s)
        s.set_defaults(func=_run(v.run), _no_robot=v.no_robot)
    return p


ROBOT_OPTIONS = ("robot", "urdf", "feet")
"""The global robot options (_global_options)."""


def check_robot_options(args: argparse.Namespace) -> None:
    """Every verb honours the robot options or refuses them (never ignores them): a verb that
    takes no robot (Verb.no_robot) refuses them; for the others a profile that cannot be read is
    refused here, before any work."""
    given = [f"--{o}" for o in ROBOT_OPTIONS if getattr(args, o, None) is not None]
    if not given:
        return
    if getattr(args, "_no_robot", ""):
        raise CimlError(f"{', '.join(given)} not taken by {args.verb}: {args._no_robot}")
    profile_from_args(args)


def main(argv: list[str] | None = None) -> int:
    # DDS stays on this machine unless the user explicitly widens it (e.g. SUBNET).
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    parser = build_parser()
    verbs = set(next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices)
    args = parser.parse_args(_join_feet(list(sys.argv[1:] if argv is None else argv), verbs))
    try:
        check_robot_options(args)
        return int(args.func(args) or 0)
    except CimlError as err:
        print(ca.one_line(f"ciml {args.verb}: error: {str(err).strip() or type(err).__name__}"), file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"ciml {args.verb}: interrupted", file=sys.stderr)
        return 130
    except (OSError, MemoryError) as err:  # the system refused something no check foresaw: still one line
        where = f" ({err.filename})" if isinstance(err, OSError) and err.filename else ""
        what = (err.strerror if isinstance(err, OSError) else None) or str(err) or type(err).__name__
        print(ca.one_line(f"ciml {args.verb}: error: {' '.join(what.split())}{where}"), file=sys.stderr)
        return EXIT_ERROR
    except Exception as err:  # a bug: one line here, the traceback with CIML_DEBUG=1
        if os.environ.get("CIML_DEBUG"):
            raise
        msg = ca.one_line(str(err), 300)
        print(ca.one_line(f"ciml {args.verb}: internal error: {type(err).__name__}: {msg} (run with CIML_DEBUG=1 "
                          "for the traceback)"), file=sys.stderr)
        return EXIT_INTERNAL


def profile_from_args(args: argparse.Namespace):
    """The robot profile of --robot (default: HyQ) with the --urdf/--feet shortcuts applied."""
    cached = getattr(args, "_profile", None)
    if cached is not None:
        return cached
    from ciml_learning.core.profile import load_profile, with_overrides

    prof = with_overrides(load_profile(getattr(args, "robot", None)), getattr(args, "urdf", None),
                          getattr(args, "feet", None))
    args._profile = prof
    return prof


def robot_from_args(args: argparse.Namespace):
    """The RobotDescription of --robot / --urdf / --feet (profile's torque limits applied)."""
    cached = getattr(args, "_robot", None)
    if cached is None:
        cached = profile_from_args(args).robot()
        args._robot = cached
    return cached


if __name__ == "__main__":
    sys.exit(main())
