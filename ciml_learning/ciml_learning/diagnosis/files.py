"""A diagnosis directory on disk: DIR/diagnosis.json and DIR/report.html, written together and read
with limits. Used by run.py (`ciml diagnose` writes the directory) and report.py (`ciml closed-loop
--report` adds its metrics to both files).
"""
from __future__ import annotations

import os

from ciml_learning.core.errors import CimlError
from ciml_learning.core.fileio import atomic_dir, json_dumps, load_json_bounded
from ciml_learning.diagnosis.effects import DiagnosisError

DIAGNOSIS_JSON, REPORT_HTML = "diagnosis.json", "report.html"
IDENTIFIED_SCENARIO = "identified_scenario.yaml"
"""The identified effects as a ciml_sim scenario (effects/scenario.identified_scenario)."""
DIAGNOSIS_MAX_BYTES = 64 * 2**20


def write_diagnosis_dir(out_dir: str, result: dict, html: str | None, what: str = "--out",
                        update: bool = False, files: dict[str, str] | None = None) -> None:
    """DIR/diagnosis.json, DIR/report.html and `files` (name → text, e.g. identified_scenario.yaml) as
    one directory published in one step (fileio.atomic_dir): a reader finds all old or all new.
    `update`: start from the existing directory's other files."""
    with atomic_dir(out_dir, is_diagnosis_dir, "diagnosis", what, copy_from_old=update) as tmp:
        with open(os.path.join(tmp, DIAGNOSIS_JSON), "w", encoding="utf-8") as f:
            f.write(json_dumps(result))
        if html is not None:
            with open(os.path.join(tmp, REPORT_HTML), "w", encoding="utf-8") as f:
                f.write(html)
        for name, text in (files or {}).items():
            with open(os.path.join(tmp, name), "w", encoding="utf-8") as f:
                f.write(text)


def read_diagnosis_json(path: str) -> dict:
    """DIR/diagnosis.json (or the file itself) with size and nesting limits; CimlError (one line)."""
    if os.path.isdir(path):
        path = os.path.join(path, DIAGNOSIS_JSON)
    doc = load_json_bounded(path, "diagnosis", DIAGNOSIS_MAX_BYTES)
    if not isinstance(doc, dict):
        raise DiagnosisError(f"{path} is not a CIML diagnosis")
    return doc


def is_diagnosis_dir(path: str) -> bool:
    """Whether `path` holds a CIML diagnosis (what `--out` may replace)."""
    try:
        read_diagnosis_json(path)
        return True
    except CimlError:
        return False
