"""Give each editable-installed ament_python package the layout ``ros2 run`` resolves.

An editable pip install installs neither setup.py's data_files nor scripts under
``lib/<pkg>``. This does both, in the venv (an ament prefix):
- ``share/ament_index/resource_index/packages/<pkg>`` (the package marker),
- ``share/<pkg>/package.xml``, ``share/<pkg>/config/`` (parameters, scenarios) and
  ``share/<pkg>/launch/`` (launch files),
- ``lib/<pkg>/<exe>``: a link to each console script of the package in ``bin/``.
"""
import os
import shutil
import sys
from importlib.metadata import distribution


def main(root: str, venv: str, packages: list[str]) -> int:
    for pkg in packages:
        src = os.path.join(root, pkg)
        index = os.path.join(venv, "share", "ament_index", "resource_index", "packages")
        os.makedirs(index, exist_ok=True)
        shutil.copyfile(os.path.join(src, "resource", pkg), os.path.join(index, pkg))
        share = os.path.join(venv, "share", pkg)
        shutil.rmtree(share, ignore_errors=True)
        os.makedirs(share)
        for folder in ("config", "launch"):  # parameters and scenarios; launch files
            if os.path.isdir(os.path.join(src, folder)):
                shutil.copytree(os.path.join(src, folder), os.path.join(share, folder))
        shutil.copyfile(os.path.join(src, "package.xml"), os.path.join(share, "package.xml"))
        dest = os.path.join(venv, "lib", pkg)
        shutil.rmtree(dest, ignore_errors=True)  # drop executables no longer registered
        os.makedirs(dest)
        for ep in distribution(pkg).entry_points:
            if ep.group != "console_scripts":
                continue
            target = os.path.join(venv, "bin", ep.name)
            if not os.path.exists(target):
                raise SystemExit(f"console script {target} missing for {pkg}")
            os.symlink(os.path.relpath(target, dest), os.path.join(dest, ep.name))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2], sys.argv[3:]))
