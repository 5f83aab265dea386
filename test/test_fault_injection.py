"""Nothing lost, nothing silently corrupted (docs/ARCHITECTURE.md, "Files: atomic outputs and checks").

- Killed at every write/fsync/rename step (fileio's CIML_FAULT_AT hook: os._exit(137), as
  kill -9; and, where strace exists, SIGKILL injected at the rename system calls), the
  model directory (ModelSet.save: what `ciml train` writes), the bag (`ciml record`), the
  diagnosis directory (`ciml diagnose`, `ciml closed-loop --report`) and the online
  learner's snapshots are the complete old one, the complete new one, or absent — in every
  trial; the next run cleans what the killed one left.
- Flipped bytes in every MCAP region and in each model file are one-line errors.
- `--out` on a device node is refused.
"""
from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
import textwrap

import pytest

from ciml_learning.core.fileio import FAULT_ENV
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.model_files import MODEL_JSON, MODEL_NPZ, ModelFileError
from ciml_learning.learning.models import ModelSet
from ciml_learning.learning.synthetic import fit_arguments, synthetic_training_set
from ciml_learning.logs.bagio import BagError, read_messages
from ciml_learning.logs.mcap_check import BagCorruptError, check_bag, seal_mcap, verify_mcap

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BAG = os.path.join(ROOT, "bags", "nominal_stand")
ROBOT = load_robot()
MAX_STEPS = 40


@pytest.fixture(scope="module")
def old_model(tmp_path_factory) -> str:
    d = synthetic_training_set(ROBOT, 600, seed=1)
    ms = ModelSet.for_robot(ROBOT, "lwpr").fit(*fit_arguments(d))
    ms.training_ = {"tag": "old"}
    out = str(tmp_path_factory.mktemp("models") / "old")
    ms.save(out)
    return out


def run_with_fault(script: str, step: int | None, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": ROOT}
    env.pop(FAULT_ENV, None)
    if step is not None:
        env[FAULT_ENV] = str(step)
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script), *args], env=env, capture_output=True,
                          text=True, timeout=180)


def every_step(script: str, check, *args: str) -> int:
    """Kill the script before each fault point in turn until it completes; check() after each."""
    for step in range(1, MAX_STEPS):
        r = run_with_fault(script, step, *args)
        assert r.returncode in (0, 137), r.stderr[-2000:]
        check(killed=r.returncode == 137)
        if r.returncode == 0:
            return step - 1
    raise AssertionError("the script never completed")


def tag_of(model_dir: str) -> str | None:
    """'old'/'new' of a complete model directory (verified load), None if absent."""
    if not os.path.lexists(model_dir):
        return None
    return ModelSet.load(model_dir, ROBOT).training_["tag"]


SAVE_MODEL = """
    import sys
    from ciml_learning.learning.models import ModelSet
    ms = ModelSet.load(sys.argv[1])
    ms.training_ = {"tag": "new"}
    ms.save(sys.argv[2])
"""


@pytest.mark.slow
def test_model_save_killed_at_every_step_is_old_or_new(old_model, tmp_path):
    out = str(tmp_path / "model")
    seen = set()

    def check(killed: bool) -> None:
        seen.add(tag_of(out))
        leftovers = [n for n in os.listdir(tmp_path) if n.startswith(".")]
        assert len(leftovers) <= 2  # a killed run's temporaries (cleaned by the next)

    # no model yet: absent or new
    steps = every_step(SAVE_MODEL, check, old_model, out)
    assert steps >= 4 and seen == {None, "new"}
    # an old model in place: old or new, never absent (renameat2 exchange), never mixed
    shutil.rmtree(out)
    shutil.copytree(old_model, out)
    seen.clear()
    every_step(SAVE_MODEL, check, old_model, out)
    assert seen == {"old", "new"}
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]  # cleaned by the last run


SNAPSHOT = """
    import sys
    import numpy as np
    from ciml_learning.learning.models import ModelSet
    from ciml_learning.learning.snapshots import Snapshot, SnapshotWriter
    ms = ModelSet.load(sys.argv[1])
    w = SnapshotWriter(sys.argv[2], keep=1)
    for k in range(2):  # the second write also removes the first snapshot
        ms.training_ = {"tag": "new"}
        w.write(Snapshot(model_set=ms, samples=10 + k, stamps=np.arange(k + 1), copy_seconds=0.0))
"""


@pytest.mark.slow
def test_snapshot_writer_killed_at_every_step_leaves_loadable_snapshots(old_model, tmp_path):
    from ciml_learning.learning.snapshots import Snapshot  # noqa: F401 - the fields the script uses exist

    root = tmp_path / "online"

    def check(killed: bool) -> None:
        if not root.exists():
            return
        for name in os.listdir(root):
            p = root / name
            if name.startswith("snapshot-"):
                assert tag_of(str(p)) == "new"
        latest = root / "latest"
        if os.path.lexists(latest):
            assert tag_of(str(latest)) == "new"  # never a dangling or half-written target

    every_step(SNAPSHOT, check, old_model, str(root))
    assert len([n for n in os.listdir(root) if n.startswith("snapshot-")]) == 1


DIAG = """
    import sys
    from ciml_learning.diagnosis.files import write_diagnosis_dir
    from ciml_learning.diagnosis.report import attach_closed_loop
    out, tag = sys.argv[1], sys.argv[2]
    write_diagnosis_dir(out, {"format_version": 1, "tag": tag},
                        f"<html>{tag}<!--closed-loop--><!--/closed-loop--></html>")
    attach_closed_loop(out, {"nominal": {"rms_feedback_effort_nm": 1.0}})
"""


def diag_state(out: str) -> str | None:
    if not os.path.lexists(out):
        return None
    doc = json.load(open(os.path.join(out, "diagnosis.json")))
    page = open(os.path.join(out, "report.html")).read()
    assert doc["tag"] in page  # both files of the same write
    return f"{doc['tag']}{'+cl' if 'closed_loop' in doc else ''}"


@pytest.mark.slow
def test_diagnosis_dir_killed_at_every_step_is_old_or_new(tmp_path):
    out = str(tmp_path / "diag")
    r = run_with_fault(DIAG, None, out, "old")
    assert r.returncode == 0, r.stderr
    seen = set()
    every_step(DIAG, lambda killed: seen.add(diag_state(out)), out, "new")
    assert seen == {"old+cl", "new", "new+cl"}


@pytest.mark.slow
def test_record_killed_at_every_step_leaves_no_bag_or_a_whole_bag(tmp_path):
    out = str(tmp_path / "bag")
    script = """
        import sys
        from ciml_learning.cli.main import main
        sys.exit(main(["record", "--scenario", "nominal", "--motion", "stand", "--duration", "0.2",
                       "--out", sys.argv[1]]))
    """
    seen = set()

    def check(killed: bool) -> None:
        if not os.path.lexists(out):
            seen.add("absent")
            return
        msgs = read_messages(out, ["/joint_states"])  # complete, CRCs verified
        assert len(msgs["/joint_states"]) > 0
        seen.add("whole")
        if killed:
            shutil.rmtree(out)  # so the next trial writes again

    every_step(script, check, out)
    assert seen == {"absent", "whole"}
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]  # stale partial folders cleaned


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("strace") is None, reason="strace not installed")
def test_sigkill_at_each_rename_syscall_is_old_or_new(tmp_path):
    """The same promise under a real SIGKILL at the rename system calls (strace -e inject)."""
    out = str(tmp_path / "diag")
    assert run_with_fault(DIAG, None, out, "old").returncode == 0
    seen = set()
    for n in range(1, 12):
        cmd = ["strace", "-f", "-qq", "-o", "/dev/null",
               "-e", f"inject=rename,renameat,renameat2:signal=SIGKILL:when={n}",
               sys.executable, "-c", textwrap.dedent(DIAG), out, "new"]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": ROOT})
        if r.returncode != 0 and "ptrace" in r.stderr.lower():
            pytest.skip("ptrace not permitted here")
        seen.add(diag_state(out))
        if r.returncode == 0:
            break
    assert seen <= {"old+cl", "new", "new+cl"} and "new+cl" in seen and len(seen) >= 2


# ---------------------------------------------------------------------- flipped bytes
@pytest.fixture(scope="module")
def sealed_bag(tmp_path_factory) -> str:
    d = tmp_path_factory.mktemp("bags") / "sealed"
    shutil.copytree(BAG, d)
    for f in d.glob("*.mcap"):
        seal_mcap(f)
    check_bag(d)
    return str(d)


def _regions(path: str) -> dict[str, int]:
    from ciml_learning.logs.mcap_check import _layout

    with open(path, "rb") as f:
        buf = f.read()
    lay = _layout(buf, path)
    c = lay.chunks[len(lay.chunks) // 2]
    return {"header": 12, "chunk": c.data_at + c.data_size // 2,
            "message_index": c.offset + 9 + (c.data_at - c.offset) + c.data_size + 12,
            "summary_index": lay.summary_start + 20, "footer": lay.footer + 12}


@pytest.mark.parametrize("region", ["header", "chunk", "message_index", "summary_index", "footer"])
def test_flipped_bytes_in_each_mcap_region_are_one_line_errors(sealed_bag, region, tmp_path, capsys):
    bag = tmp_path / "bag"
    shutil.copytree(sealed_bag, bag)
    mcap = next(bag.glob("*.mcap"))
    off = _regions(str(mcap))[region]
    data = bytearray(mcap.read_bytes())
    data[off:off + 4] = bytes(b ^ 0xFF for b in data[off:off + 4])
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagCorruptError) as info:
        verify_mcap(mcap)
    assert "\n" not in str(info.value) and "byte" in str(info.value)
    with pytest.raises(BagError):
        read_messages(str(bag), ["/joint_states"])
    from ciml_learning.cli.main import main

    assert main(["extract", "--bag", str(bag), "--out", str(tmp_path / "t.npz")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "byte" in err and "mcap recover" in err, err
    assert not (tmp_path / "t.npz").exists()


def test_unsealed_zstd_chunk_of_zeros_is_one_line(tmp_path):
    """A bag without CRCs (other writers): a garbled compressed chunk is caught by decoding it."""
    bag = tmp_path / "bag"
    shutil.copytree(BAG, bag)
    mcap = next(bag.glob("*.mcap"))
    lay_off = _regions(str(mcap))["chunk"]
    data = bytearray(mcap.read_bytes())
    data[lay_off:lay_off + 4096] = bytes(4096)
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError) as info:
        read_messages(str(bag), ["/joint_states"])
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("name", [MODEL_NPZ, MODEL_JSON])
def test_flipped_byte_in_each_model_file_is_one_line(old_model, name, tmp_path):
    d = tmp_path / "m"
    shutil.copytree(old_model, d)
    data = bytearray((d / name).read_bytes())
    i = len(data) // 2
    data[i] = (data[i] + 1) % 256 if name == MODEL_NPZ else ord("7" if data[i] != ord("7") else "8")
    (d / name).write_bytes(bytes(data))
    with pytest.raises(ModelFileError) as info:
        ModelSet.load(str(d), ROBOT)
    assert "\n" not in str(info.value)


def test_out_on_a_device_node_is_refused(old_model, tmp_path, capsys):
    dev = tmp_path / "null"
    try:
        os.mknod(dev, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except (PermissionError, OSError) as err:
        pytest.skip(f"mknod not permitted: {err}")
    from ciml_learning.cli.main import main

    for argv in (["evaluate", "--model", old_model, "--bag", BAG, "--out", str(dev)],
                 ["train", "--bag", BAG, "--learner", "lwpr", "--out", str(dev)],
                 ["extract", "--bag", BAG, "--out", str(dev)]):
        assert main(argv) == 1
        err = capsys.readouterr().err.strip()
        assert "character device" in err and err.count("\n") == 0, err
        assert stat.S_ISCHR(os.lstat(dev).st_mode)
    link = tmp_path / "link.json"
    link.symlink_to("/etc/hostname")
    assert main(["evaluate", "--model", old_model, "--bag", BAG, "--out", str(link)]) == 1
    assert "symbolic link" in capsys.readouterr().err and os.path.islink(link)


def test_duplicated_messages_are_counted_as_dropped(tmp_path):
    """A log with repeated joint-state messages: each repeat is a counted drop, not a silent one."""
    from ciml_learning.logs.bagio import BagWriter, iter_bag_messages
    from ciml_learning.logs.loginputs import load_log

    clean = load_log(ROBOT, BAG)
    out = tmp_path / "dup"
    repeats = 0
    with BagWriter(out) as w:
        seen = 0
        for topic, ns, raw, msgtype in iter_bag_messages(BAG):
            w.write_serialized(topic, ns, raw, msgtype)
            if topic == "/joint_states":
                seen += 1
                if seen % 10 == 0:
                    w.write_serialized(topic, ns, raw, msgtype)
                    repeats += 1
    log = load_log(ROBOT, str(out))
    dropped = {k: v for k, v in log.rejected.items() if "duplicated stamp" in k}
    assert repeats > 0 and sum(dropped.values()) == repeats, log.rejected
    assert len(log) == len(clean)


@pytest.mark.slow
def test_ciml_train_killed_while_publishing_keeps_old_or_new(old_model, tmp_path):
    """The real `ciml train` (same ModelSet.save as above): killed at the exchange the old
    model is intact; killed after it (before removing the old copy) the new one is in place."""
    script = """
        import sys
        from ciml_learning.cli.main import main
        sys.exit(main(["train", "--bag", sys.argv[1], "--learner", "lwpr", "--jobs", "1", "--out", sys.argv[2]]))
    """
    for step, expect in (("exchange:1", "old"), ("cleanup:1", "new")):
        out = tmp_path / step.replace(":", "_") / "model"  # its own folder: no temporaries of the other trial
        shutil.copytree(old_model, out)
        r = subprocess.run([sys.executable, "-c", textwrap.dedent(script), BAG, str(out)], capture_output=True,
                           text=True, timeout=300, env={**os.environ, "PYTHONPATH": ROOT, FAULT_ENV: step})
        assert r.returncode == 137, r.stderr[-2000:]
        ms = ModelSet.load(str(out), ROBOT)  # complete and verified either way
        assert (ms.training_.get("tag") == "old") == (expect == "old")
        if expect == "new":
            assert ms.training_["bags"] == [BAG]


def test_recording_killed_mid_run_leaves_nothing_at_out_and_is_cleaned(tmp_path):
    """kill -9 while messages are being written: no bag at --out; the next writer removes the
    dead run's partial folder."""
    from ciml_learning.logs.bagio import BagWriter

    out = tmp_path / "bag"
    script = """
        import sys, time
        from ciml_learning.logs.bagio import BagWriter
        from ciml_learning.core import topics
        with BagWriter(sys.argv[1]) as w:
            for k in range(50):
                w.write_serialized(topics.JOINT_STATES, k, b"\\x00\\x01\\x00\\x00" + bytes(60),
                                   "sensor_msgs/msg/JointState")
            print("writing", flush=True)
            time.sleep(60)
    """
    p = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script), str(out)], stdout=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONPATH": ROOT})
    try:
        assert p.stdout.readline().strip() == "writing"
        partial = [n for n in os.listdir(tmp_path) if n.startswith(".bag.partial-")]
        assert len(partial) == 1
        p.kill()
        p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert not out.exists()
    with BagWriter(out):
        pass
    assert os.listdir(tmp_path) == ["bag"]


def test_nested_json_and_yaml_alias_bombs_are_one_line(tmp_path):
    from ciml_learning.core.fileio import InputFileError, load_json_bounded, load_yaml_bounded

    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(InputFileError, match="nested deeper"):
        load_json_bounded(str(deep))
    model = tmp_path / "m"
    model.mkdir()
    (model / MODEL_JSON).write_text('{"a":' * 5000 + "1" + "}" * 5000)
    with pytest.raises(ModelFileError, match="nested deeper") as info:
        ModelSet.load(str(model), ROBOT)
    assert "\n" not in str(info.value)
    bomb = tmp_path / "bomb.yaml"
    lines = ['a0: &a0 ["x", "x", "x", "x", "x", "x", "x", "x", "x"]']
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    bomb.write_text("\n".join(lines) + "\n")
    assert bomb.stat().st_size < 1000
    with pytest.raises(InputFileError, match="expands to more than") as info:
        load_yaml_bounded(str(bomb))
    assert len(str(info.value)) < 300
    big = tmp_path / "big.yaml"
    big.write_text("x: " + "y" * (2**20 + 10))
    with pytest.raises(InputFileError, match="larger than"):
        load_yaml_bounded(str(big))


@pytest.mark.slow
def test_closed_loop_report_killed_at_every_step_keeps_the_diagnosis_whole(tmp_path):
    """The real `ciml closed-loop --report DIAG` (the diagnosis folder rewritten by the same
    write_diagnosis_dir as `ciml diagnose`): killed at every step, DIAG holds both files of
    the old or both of the new write, and the result JSON is absent or complete."""
    from ciml_learning.diagnosis.files import write_diagnosis_dir

    diag, result = str(tmp_path / "diag"), tmp_path / "r.json"
    write_diagnosis_dir(diag, {"format_version": 1, "tag": "old"},
                        "<html>old<!--closed-loop--><!--/closed-loop--></html>")
    script = """
        import sys
        from ciml_learning.cli.main import main
        sys.exit(main(["closed-loop", "--scenario", "nominal", "--motion", "stand", "--model", "nominal",
                       "--duration", "0.2", "--out", sys.argv[1], "--report", sys.argv[2]]))
    """
    seen = set()

    def check(killed: bool) -> None:
        doc = json.load(open(os.path.join(diag, "diagnosis.json")))
        page = open(os.path.join(diag, "report.html")).read()
        with_nominal = "nominal" in doc.get("closed_loop", {})
        assert with_nominal == ("<td>nominal</td>" in page)  # the two files agree
        seen.add(with_nominal)
        if result.exists():
            assert "metrics" in json.loads(result.read_text())

    every_step(script, check, str(result), diag)
    assert seen == {False, True}


def test_corrupt_db3_is_one_line(tmp_path):
    """sqlite3 bags: a damaged page or a file that is not a database are one-line errors."""
    import sqlite3

    bag = tmp_path / "bag"
    bag.mkdir()
    db = bag / "bag_0.db3"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER, timestamp INTEGER, data BLOB)")
    con.execute("CREATE INDEX ts ON messages(timestamp)")
    con.executemany("INSERT INTO messages VALUES (?, 1, ?, ?)", [(i, i * 1000, os.urandom(200)) for i in range(5000)])
    con.commit()
    con.close()
    check_bag(bag)  # intact
    data = bytearray(db.read_bytes())
    page = 4096
    mid = (len(data) // page // 2) * page
    data[mid:mid + 64] = bytes(range(64))  # a b-tree page header overwritten
    db.write_bytes(bytes(data))
    with pytest.raises(BagCorruptError) as info:
        check_bag(bag)
    assert "\n" not in str(info.value) and "bag_0.db3" in str(info.value)
    db.write_bytes(b"not a database" * 100)
    with pytest.raises(BagCorruptError, match="not a readable SQLite database|integrity") as info:
        check_bag(bag)
    assert "\n" not in str(info.value)
