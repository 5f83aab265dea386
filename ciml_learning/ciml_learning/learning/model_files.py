"""The file format of a model set (model_dir/, the whole directory published in one step:
fileio.atomic_dir):

    model.npz   arrays only, read with allow_pickle=False: input_mean, input_scale,
                output_scale, and "dimNN.<key>" for each learned dimension NN
                (learner state, see the learners' get_state)
    model.json  format_version, learner, kernel, hyper-parameters, input/output names,
                the robot's joint and foot names, training bags and sample counts,
                per-dimension summaries, the npz's sha256 and size, a `manifest` (sha256
                and size of every other file of the directory) and a `checksum`: the
                sha256 of the JSON body itself without the checksum (canonical form,
                model_checksum) — so the description is covered too

Loading checks the version, the learner against an allow-list, the JSON checksum, every
manifest file's checksum, the robot's names, then rebuilds each learner from its arrays —
no pickle, no GPy save/load, no name from the file is ever evaluated. Any mismatch raises
ModelFileError (one line).
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import time
import zipfile
from typing import Any

import numpy as np

from ciml_learning.core.errors import CimlError

FORMAT_VERSION = 5
"""5: model.json carries a manifest and its own checksum; 4: the actuation models take τ and τ̇
too; 3: the rigid-body models learn Φ̃ = J'ᵀΦ̃' (base wrench, leg joints). Other versions are
refused."""
MODEL_JSON_MAX_BYTES = 16 * 2**20
MODEL_JSON = "model.json"
MODEL_NPZ = "model.npz"
KIND = "ciml_model_set"
KERNELS = {"lwpr": "gaussian_receptive_fields", "sgpr": "matern32_ard"}


class ModelFileError(CimlError):
    """A model directory that cannot be used: missing, truncated, tampered, wrong version or robot."""


def model_checksum(meta: dict[str, Any]) -> str:
    """sha256 of model.json's body without its `checksum` (sorted keys, compact separators)."""
    body = {k: v for k, v in meta.items() if k != "checksum"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":"),
                                     allow_nan=False).encode("utf-8")).hexdigest()


def is_model_dir(path: str) -> bool:
    """Whether `path` holds a CIML model description (what `--out` may replace)."""
    from ciml_learning.core.fileio import load_json_bounded

    try:
        meta = load_json_bounded(os.path.join(path, MODEL_JSON), "model description", MODEL_JSON_MAX_BYTES)
    except CimlError:
        return False
    return isinstance(meta, dict) and meta.get("kind") == KIND


def read_metadata(model_dir: str) -> dict[str, Any]:
    """model.json of a model directory, with its format version, learner and checksum checked."""
    from ciml_learning.core.fileio import InputFileError, load_json_bounded

    path = os.path.join(model_dir, MODEL_JSON)
    if not os.path.isdir(model_dir):
        raise ModelFileError(f"model directory not found: {model_dir}")
    if not os.path.lexists(path):
        raise ModelFileError(f"{path} not found (not a model directory)")
    try:
        meta = load_json_bounded(path, "model description", MODEL_JSON_MAX_BYTES)
    except InputFileError as err:
        raise ModelFileError(str(err)) from None
    if not isinstance(meta, dict):
        raise ModelFileError(f"{path} is not a CIML model description")
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise ModelFileError(f"{path} has format_version {version!r}; this CIML reads version {FORMAT_VERSION} "
                             "(retrain with `ciml train`)")
    if meta.get("kind") != KIND:
        raise ModelFileError(f"{path} is not a CIML model set (kind {meta.get('kind')!r})")
    if meta.get("learner") not in KERNELS:
        raise ModelFileError(f"{path} names unknown learner {meta.get('learner')!r}; valid: {sorted(KERNELS)}")
    try:
        ok = meta.get("checksum") == model_checksum(meta)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ModelFileError(f"{path} does not match its own checksum (modified or corrupt); retrain or restore it")
    manifest = meta.get("manifest")
    if not isinstance(manifest, dict) or MODEL_NPZ not in manifest or \
            not all(isinstance(v, dict) for v in manifest.values()):
        raise ModelFileError(f"{path} has no valid manifest")
    return meta


def read_model_file(model_dir: str, meta: dict[str, Any], name: str) -> bytes:
    """One file of a model directory, checked against model.json's manifest."""
    info = meta["manifest"].get(name)
    path = os.path.join(model_dir, name)
    if info is None or os.path.basename(name) != name:
        raise ModelFileError(f"{model_dir}/{MODEL_JSON}: {name} is not in the manifest")
    try:
        with open(path, "rb") as f:
            data = f.read(int(info.get("bytes", -1)) + 1)
    except FileNotFoundError:
        raise ModelFileError(f"{path} not found") from None
    except (OSError, TypeError, ValueError) as err:
        raise ModelFileError(f"cannot read {path}: {getattr(err, 'strerror', None) or err}") from None
    if len(data) != info.get("bytes") or hashlib.sha256(data).hexdigest() != info.get("sha256"):
        raise ModelFileError(f"{path} does not match the checksum in {MODEL_JSON} (truncated, modified, or "
                             f"written by a concurrent save: reload after the next /model_update)")
    return data


def verify_model_files(model_dir: str, meta: dict[str, Any]) -> None:
    """Every file of the manifest present and intact (ModelFileError otherwise)."""
    for name in meta["manifest"]:
        read_model_file(model_dir, meta, name)


def read_arrays(model_dir: str, meta: dict[str, Any]) -> dict[str, np.ndarray]:
    """The npz's arrays, once every file of the manifest is checked (read_model_file)."""
    for name in meta["manifest"]:
        if name != MODEL_NPZ:
            read_model_file(model_dir, meta, name)
    data = read_model_file(model_dir, meta, MODEL_NPZ)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as err:
        raise ModelFileError(f"{model_dir}/{MODEL_NPZ} is not a readable npz ({err})") from None


def write_model_dir(model_dir: str, arrays: dict[str, np.ndarray], description: dict[str, Any],
                    extra_files: dict[str, bytes] | None = None, what: str = "--out") -> dict[str, Any]:
    """Write a model directory: the arrays as model.npz, `extra_files`, and model.json (the
    format's fields, `description`, the manifest, the checksum) as one new directory that
    replaces the old one in one step (fileio.atomic_dir); returns model.json's content."""
    from ciml_learning.core.fileio import atomic_dir, json_dumps

    buf = io.BytesIO()
    np.savez(buf, allow_pickle=False, **arrays)
    data = buf.getvalue()
    files = {MODEL_NPZ: data, **(extra_files or {})}
    meta = {"format_version": FORMAT_VERSION, "kind": KIND, **description,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "npz": {"file": MODEL_NPZ, "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}}
    meta["manifest"] = {name: {"sha256": hashlib.sha256(b).hexdigest(), "bytes": len(b)}
                        for name, b in sorted(files.items())}
    meta["checksum"] = model_checksum(meta)
    with atomic_dir(model_dir, is_model_dir, "model", what) as tmp:
        for name, b in files.items():
            with open(os.path.join(tmp, name), "xb") as f:
                f.write(b)
        with open(os.path.join(tmp, MODEL_JSON), "x", encoding="utf-8") as f:
            f.write(json_dumps(meta))
    return meta
