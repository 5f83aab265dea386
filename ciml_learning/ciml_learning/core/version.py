"""Which CIML this is: the package version and the commit of its source tree (for `ciml --version`
and the benchmarks' JSON)."""
from __future__ import annotations

import os
import subprocess
from importlib.metadata import PackageNotFoundError, version


def package_version() -> str:
    try:
        return version("ciml_learning")
    except PackageNotFoundError:
        return "unknown"


def source_commit() -> str:
    """The git commit of the checkout this package runs from ('' outside a git checkout), with
    '+dirty' when it has uncommitted changes."""
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=here, timeout=5)
        if head.returncode != 0:
            return ""
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, cwd=here, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return head.stdout.strip() + ("+dirty" if dirty else "")


def version_text() -> str:
    commit = source_commit()
    return f"ciml {package_version()}" + (f" (commit {commit})" if commit else "")
