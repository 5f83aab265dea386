"""`ciml closed-loop --report DIAG_DIR` adds its result to the diagnosis report's comparison."""
from __future__ import annotations

import json

import pytest

from ciml_learning.core.errors import CimlError
from ciml_learning.diagnosis.report import CLOSED_LOOP_BEGIN, CLOSED_LOOP_END
from ciml_sim.commands import _add_to_report, _model_label


def test_results_accumulate_in_the_report(tmp_path):
    diag = tmp_path / "diag"
    diag.mkdir()
    (diag / "diagnosis.json").write_text(json.dumps({"effects": []}))
    (diag / "report.html").write_text(f"<html>{CLOSED_LOOP_BEGIN}none yet{CLOSED_LOOP_END}</html>")
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.json").write_text(json.dumps({"learner": "sgpr"}))
    assert _model_label("nominal") == "nominal"
    assert _model_label(str(diag)) == "identified effects"
    assert _model_label(str(model)) == "learned (SGPR)"
    m = {"rms_feedback_effort_nm": 12.5, "rms_joint_error_deg": 0.4, "rms_attitude_error_deg": 0.2,
         "rms_base_position_error_mm": 2.0, "fell": False}
    _add_to_report(str(diag), "nominal", m)
    _add_to_report(str(diag), "identified effects", {**m, "rms_feedback_effort_nm": 3.5})
    doc = json.loads((diag / "diagnosis.json").read_text())
    assert doc["closed_loop"]["nominal"]["rms_feedback_effort_nm"] == 12.5
    assert doc["closed_loop"]["identified effects"]["rms_feedback_effort_nm"] == 3.5
    page = (diag / "report.html").read_text()
    assert "identified effects" in page and "12.5" in page and "none yet" not in page


def test_report_without_diagnosis_is_a_clear_error(tmp_path):
    with pytest.raises(CimlError, match="no readable diagnosis.json"):
        _add_to_report(str(tmp_path), "nominal", {})
