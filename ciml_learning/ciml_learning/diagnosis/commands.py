"""`ciml diagnose --bag BAG... [--heldout BAG...] [--reference REF_BAG...] --out DIR` (docs/ARCHITECTURE.md §4, §6)."""
from __future__ import annotations

import argparse
import os


def diagnose(args: argparse.Namespace) -> int:
    from ..cli import profile_from_args, robot_from_args
    from .report import answers
    from .run import diagnose as run

    robot = robot_from_args(args)
    result = run(robot, args.bag, args.heldout, args.out, progress=True, profile=profile_from_args(args),
                 reference=getattr(args, "reference", None))
    print(f"diagnosis: {os.path.join(args.out, 'diagnosis.json')}")
    print(f"report:    {os.path.join(args.out, 'report.html')}")
    for line in answers(result):
        print(line)
    for w in result["data"].get("warnings", []):
        print(f"warning: {w}")
    if getattr(args, "publish", None) is not None:  # after diagnosis.json is written
        from ..gap_publisher import publish_gap_diagnosis

        matched = publish_gap_diagnosis(result, linger=args.publish)
        print(f"published on /gap_diagnosis ({matched} subscriber(s) matched)")
    return 0
