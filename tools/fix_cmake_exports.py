"""Rewrite the build-machine include folders baked into the ROS message wheels' CMake exports.

The ``ros-*`` wheels were built under /opt/python/cp311-cp311; CMake refuses to
generate while the include folders they name do not exist (docs/ARCHITECTURE.md §10).
Idempotent: only files still naming the old folders are rewritten.
"""
import glob
import os
import sys
import sysconfig

import numpy

OLD_PY = "/opt/python/cp311-cp311/include/python3.11"
OLD_NP = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def main(venv: str) -> int:
    new_py = sysconfig.get_paths()["include"]
    new_np = numpy.get_include()
    changed = 0
    for path in glob.glob(os.path.join(venv, "share", "*", "cmake", "*Export.cmake")):
        with open(path, encoding="utf-8") as f:
            text = f.read()
        if OLD_PY not in text and OLD_NP not in text:
            continue
        # numpy first: OLD_PY is not a prefix of OLD_NP, but keep the order explicit anyway
        text = text.replace(OLD_NP, new_np).replace(OLD_PY, new_py)
        tmp = path + ".tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
        changed += 1
    print(f"[install] patched {changed} CMake export files")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
