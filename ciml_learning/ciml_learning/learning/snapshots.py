"""Snapshots of the online learner's model set on disk.

SnapshotWriter saves snapshots from a worker thread (workers.LatestOnlyWorker): the
learner's thread only pays a deep copy of the model set (timed, reported); serialisation,
checksum and fsync run on the worker. Each snapshot is a new directory
root/snapshot-NNNNNN (immutable once announced, so a server never reads a directory that
is being rewritten), `root/latest` is a symlink to the newest, and only the newest `keep`
are kept.
"""
from __future__ import annotations

import io
import os
import re
import shutil
import time
from dataclasses import dataclass

import numpy as np

from ciml_learning.core.errors import CimlError
from ciml_learning.learning.models import ModelSet
from ciml_learning.learning.snapshot_gate import Validation, ValidationConfig, keep_accepted, validate

SNAPSHOT_PREFIX = "snapshot-"
LATEST = "latest"
STAMPS_FILE = "learned_stamps.npy"
"""Optional file of a snapshot: int64 header stamps [ns] of the learned samples, in order."""
PROBE_FILE = "probe_inputs.npy"
VALIDATION_FILE = "validation.json"
"""File of a snapshot: float64 (k × n_inputs) learning inputs x drawn uniformly from the learned
samples (reservoir sampling), on which the model server checks the model's predictions."""


@dataclass
class Snapshot:
    """A frozen copy of the learner's model set, handed to the SnapshotWriter."""

    model_set: ModelSet
    samples: int                   # pairs learned when the copy was taken
    stamps: np.ndarray | None      # learned stamps [ns], in order (record_stamps only)
    copy_seconds: float            # time the learning thread spent copying
    probe_inputs: np.ndarray | None = None  # a uniform sample of the learned inputs x (k × n_inputs)
    heldout: tuple[np.ndarray, ...] | None = None  # held-back samples to validate on (snapshot_gate)



@dataclass
class SavedSnapshot:
    model_dir: str
    learner: str
    samples: int
    checksum: str
    write_seconds: float
    validation: Validation | None = None  # the gate's decision; refused: nothing written, model_dir ''


class SnapshotWriter:
    """Numbered snapshot directories under `root` (module docstring); write() is what
    the worker thread runs. Numbering continues after existing snapshots. With `validation`,
    a snapshot that carries held-back samples is first put to the gate of snapshot_gate: refused,
    nothing is written; accepted, it is written with its accepted outputs only and the decision
    (VALIDATION_FILE, in the manifest and so in the checksum)."""

    def __init__(self, root: str, keep: int = 3, validation: ValidationConfig | None = None) -> None:
        if keep < 1:
            raise ValueError("keep must be >= 1")
        self.root = os.path.abspath(os.path.expanduser(root))
        self.keep = int(keep)
        self.validation = validation
        try:
            os.makedirs(self.root, exist_ok=True)
            existing = self.snapshots()
        except OSError as err:
            raise CimlError(f"cannot use snapshot folder {self.root}: {err.strerror or err}") from err
        self.seq = existing[-1][0] if existing else 0

    def snapshots(self) -> list[tuple[int, str]]:
        """(number, path) of the snapshot directories, oldest first."""
        out = []
        for name in os.listdir(self.root):
            m = re.fullmatch(rf"{SNAPSHOT_PREFIX}(\d+)", name)
            if m and os.path.isdir(os.path.join(self.root, name)):
                out.append((int(m.group(1)), os.path.join(self.root, name)))
        return sorted(out)

    def write(self, snap: Snapshot) -> SavedSnapshot:
        """Write the next snapshot directory (published whole: fileio.atomic_dir, the stamps in
        its manifest), then point `latest` at it (a symlink swapped with one rename), then
        remove snapshots beyond `keep`. Killed at any step: every snapshot-NNNNNN is complete."""
        from ciml_learning.core.fileio import clean_stale, fault_point, fsync_dir, json_dumps

        t0 = time.perf_counter()
        extra = {}
        decision = None
        if self.validation is not None and snap.heldout is not None:
            decision = validate(snap.model_set, snap.heldout, snap.samples, self.validation)
            if not decision.served:
                return SavedSnapshot("", snap.model_set.learner, int(snap.samples), "",
                                     time.perf_counter() - t0, decision)
            keep_accepted(snap.model_set, decision)
            extra[VALIDATION_FILE] = json_dumps(decision.to_json(snap.model_set.output_names)).encode()
        self.seq += 1
        name = f"{SNAPSHOT_PREFIX}{self.seq:06d}"
        path = os.path.join(self.root, name)
        clean_stale(self.root, rf"{SNAPSHOT_PREFIX}\d+|{LATEST}")
        if snap.stamps is not None:
            buf = io.BytesIO()
            np.save(buf, snap.stamps.astype(np.int64), allow_pickle=False)
            extra[STAMPS_FILE] = buf.getvalue()
        if snap.probe_inputs is not None and len(snap.probe_inputs):
            buf = io.BytesIO()
            np.save(buf, snap.probe_inputs.astype(np.float64), allow_pickle=False)
            extra[PROBE_FILE] = buf.getvalue()
        snap.model_set.training_ = {**snap.model_set.training_, "source": "online_learner",
                                    "samples": int(snap.samples), "snapshot": self.seq}
        meta = snap.model_set.save(path, extra_files=extra, what="snapshot")
        tmp = os.path.join(self.root, f".{LATEST}.tmp-{os.getpid()}")
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(name, tmp)
        fault_point("rename")
        os.replace(tmp, os.path.join(self.root, LATEST))
        fsync_dir(self.root)
        for _, old in self.snapshots()[: -self.keep]:
            fault_point("cleanup")
            shutil.rmtree(old, ignore_errors=True)
        return SavedSnapshot(path, snap.model_set.learner, int(snap.samples), meta["checksum"],
                             time.perf_counter() - t0, decision)


