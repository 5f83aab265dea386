"""Implementations of the learning-side `ciml` verbs (argument namespace in, exit code out)."""
from __future__ import annotations

import argparse
import json

from .errors import CimlError


def play(args: argparse.Namespace) -> int:
    from .replay import play_bag

    counts = play_bag(args.bag, rate=args.rate)
    print(json.dumps({"published": counts}))
    return 0


def bench(args: argparse.Namespace) -> int:
    from .bench import run

    run(args.only, args.out)
    return 0
