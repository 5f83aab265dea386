"""`ciml export-mjcf --diagnosis DIR --mjcf MODEL.xml --out PATCHED.xml`: a diagnosis's physical effects
in the user's own MuJoCo model, its sensor effects in a calibration file (docs/DIAGNOSIS.md).

Every identified effect of DIR/diagnosis.json goes through its type's MuJoCo form (the registry,
ciml_learning/effects/<type>.py: patch_mjcf, with ciml_learning.effects.mjcf's edits): viscous
friction → joint damping, Coulomb friction → frictionloss, payload → a body welded to the base, link
mass scale → the body's inertial, torque gain/offset → the actuator's gain/bias, actuator lag →
dyntype filterexact. Sensor effects (encoder offset, torque-sensor gain/offset, IMU tilt) belong to
the driver: they go to sensor_calibration.yaml beside PATCHED.xml. A type MuJoCo cannot express
(Stribeck friction) is listed as not exportable. Every name is matched before anything is written;
the patched model must compile (mujoco.MjModel); outputs are written atomically (fileio).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile

import mujoco
import yaml

from ciml_learning.core.fileio import atomic_write_text, check_out_parent, read_bounded
from ciml_learning.diagnosis import DiagnosisError
from ciml_learning.diagnosis.effects import effects_from_diagnosis
from ciml_learning.diagnosis.files import read_diagnosis_json
from ciml_learning.effects import effect_type
from ciml_learning.effects.mjcf import MjcfError, MjcfPatch

MJCF_MAX_BYTES = 16 * 2**20
CALIBRATION = "sensor_calibration.yaml"
CORRECTION = {  # how a driver undoes each sensor effect (measured = what the sensor reports)
    "encoder_offset": "q = q_measured - value",
    "torque_sensor_gain": "tau = (tau_measured - offset) / value (offset: torque_sensor_offset of the joint, else 0)",
    "torque_sensor_offset": "tau = (tau_measured - value) / gain (gain: torque_sensor_gain of the joint, else 1)",
    "base_imu_tilt": "R = R_measured · R_rpy(roll, pitch, 0)ᵀ",
}


def export(effects: list[dict], mjcf_text: str, source: str) -> tuple[str, list[dict], list[dict], list[dict]]:
    """(patched MJCF text, exported effects, sensor calibration entries, effects not exportable)."""
    patch = MjcfPatch(mjcf_text, source)
    exported, calibration, not_exportable = [], [], []
    for e in effects:
        kind = effect_type(e.get("type"))
        where = {k: e[k] for k in ("joint", "joints", "link") if k in e}
        if kind.measurement_only:
            calibration.append({"type": kind.name, **where, **e["params"], "correction": CORRECTION[kind.name]})
        elif kind.mujoco is None:
            not_exportable.append({"type": kind.name, **where, "why": kind.mujoco_note})
        else:
            kind.patch_mjcf(patch, e)
            exported.append({"type": kind.name, **where, "as": kind.mujoco})
    return patch.text(), exported, calibration, not_exportable


def _compile(text: str, source: str) -> None:
    """mujoco.MjModel of the patched text, compiled beside the source (its relative asset paths)."""
    folder = os.path.dirname(os.path.abspath(source))
    fd, tmp = tempfile.mkstemp(prefix=".ciml-export-", suffix=".xml", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        mujoco.MjModel.from_xml_path(tmp)
    except ValueError as err:
        raise MjcfError(f"the patched {source} does not compile: {str(err).splitlines()[0]}") from None
    finally:
        os.unlink(tmp)


def export_mjcf_command(args: argparse.Namespace) -> int:
    check_out_parent(args.out, "--out")
    doc = read_diagnosis_json(args.diagnosis)
    effects, _ = effects_from_diagnosis(doc)
    if not effects:
        raise DiagnosisError(f"{args.diagnosis}: the diagnosis identified no effect; nothing to export")
    text = read_bounded(args.mjcf, MJCF_MAX_BYTES, "MJCF file").decode("utf-8", errors="strict")
    patched, exported, calibration, not_exportable = export(effects, text, args.mjcf)
    _compile(patched, args.mjcf)
    atomic_write_text(args.out, patched)
    calib_path = None
    if calibration:
        calib_path = os.path.join(os.path.dirname(os.path.abspath(args.out)), CALIBRATION)
        atomic_write_text(calib_path, "# ciml export-mjcf: sensor effects belong to the driver, not the physics\n"
                          + yaml.safe_dump({"sensors": calibration}, sort_keys=False))
    print(json.dumps({"out": args.out, "exported": exported, "sensor_calibration": calib_path,
                      "not_exportable": not_exportable}))
    return 0
