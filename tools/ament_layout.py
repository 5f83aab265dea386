"""Give each installed ament_python package the layout ``ros2 run`` resolves.

``ros2 run PKG EXE`` looks for ``<prefix>/lib/PKG/EXE``. pip puts console scripts into
``<venv>/bin``; this links each console script of PKG into ``<venv>/lib/PKG/``.
The package marker and package.xml are installed by setup.py's data_files.
"""
import os
import sys
from importlib.metadata import distribution


def main(venv: str, packages: list[str]) -> int:
    for pkg in packages:
        dist = distribution(pkg)
        dest = os.path.join(venv, "lib", pkg)
        os.makedirs(dest, exist_ok=True)
        for old in os.listdir(dest):  # drop executables no longer registered
            os.unlink(os.path.join(dest, old))
        for ep in dist.entry_points:
            if ep.group != "console_scripts":
                continue
            target = os.path.join(venv, "bin", ep.name)
            if not os.path.exists(target):
                raise SystemExit(f"console script {target} missing for {pkg}")
            os.symlink(os.path.relpath(target, dest), os.path.join(dest, ep.name))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2:]))
