"""The YAML launch subset of `ciml launch` (ciml_learning.ros.launch_file) and its process runner,
without ROS: parsing, substitutions, conditions, parameter typing, errors, signals."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import yaml

from ciml_learning.ros import launch_file as lf
from ciml_learning.ros.launcher import Launcher


def _share(pkg: str) -> str:
    return f"/prefix/share/{pkg}"


def _write(tmp_path, text: str) -> str:
    path = tmp_path / "t.launch.yaml"
    path.write_text(textwrap.dedent(text))
    return str(path)


@pytest.mark.parametrize("value,expected", [("250.0", 250.0), ("3", 3), ("true", True), ("False", False),
                                            ("", ""), ("trot_35", "trot_35"), ("[1, 2]", [1, 2]),
                                            ("a: b", "a: b"), ("null", "null")])
def test_parameter_values_are_typed_as_launch_ros_types_them(value, expected):
    got = lf.parameter_value(value)
    assert got == expected and type(got) is type(expected)
    # and the -p text reads back as the same value
    back = lf.parameter_value(lf.parameter_text(got)) if got != "" else yaml.safe_load(lf.parameter_text(got))
    assert back == expected


def test_substitutions_conditions_and_let(tmp_path, monkeypatch):
    monkeypatch.setenv("CIML_TEST_ENV", "from_env")
    monkeypatch.delenv("CIML_UNSET", raising=False)
    path = _write(tmp_path, """
        launch:
        - arg: {name: a, default: "1"}
        - let: {name: b, value: "$(var a)-$(env CIML_TEST_ENV)-$(env CIML_UNSET dflt)"}
        - node: {pkg: p, exec: e1, name: n1, param: [{name: x, value: "$(var b)"}, {name: d, value: "$(dirname)"}],
                 remap: [{from: /in, to: /out}], namespace: ns}
        - node: {pkg: p, exec: e2, if: "$(var a)"}
        - node: {pkg: p, exec: e3, unless: "$(var a)"}
        """)
    desc = lf.load(path, {}, find_share=_share)
    assert [n.executable for n in desc.nodes] == ["e1", "e2"]
    n1 = desc.nodes[0]
    assert dict(n1.parameters) == {"x": "1-from_env-dflt", "d": str(tmp_path)}
    assert n1.ros_arguments() == ["--ros-args", "-r", "__node:=n1", "-r", "__ns:=/ns", "-p", "x:=1-from_env-dflt",
                                  "-p", f"d:={tmp_path}", "-r", "/in:=/out"]
    desc = lf.load(path, {"a": "0"}, find_share=_share)
    assert [n.executable for n in desc.nodes] == ["e1", "e3"]


@pytest.mark.parametrize("text,args,message", [
    ("launch:\n- include: {file: x}\n", {}, "unsupported action 'include'"),
    ("launch:\n- node: {pkg: p, exec: e, param: [{name: x, value: '$(command ls)'}]}\n", {},
     "unsupported substitution"),
    ("launch:\n- node: {pkg: p, exec: e, param: [{name: x, value: '$(var nope)'}]}\n", {}, "'nope' is not set"),
    ("launch:\n- arg: {name: a}\n", {}, "'a' is required"),
    ("launch:\n- arg: {name: a, default: x}\n", {"b": "1"}, "unknown launch argument(s) b"),
    ("launch:\n- arg: {name: a, default: maybe}\n- node: {pkg: p, exec: e, if: $(var a)}\n", {},
     "neither true nor false"),
    ("launch:\n- node: {pkg: p, exec: e, respawn: true}\n", {}, "unsupported node attribute(s) respawn"),
    ("launch:\n- node: {pkg: p}\n", {}, "missing exec"),
    ("nodes: []\n", {}, "not a YAML launch file"),
    ("launch: [\n", {}, "not valid YAML"),
    ("launch:\n- node: {pkg: p, exec: e, param: [{name: x, value: '$(env CIML_UNSET)'}]}\n", {}, "is not set"),
    ("launch:\n- node: {pkg: p, exec: e}\n- set_env: {name: A, value: b}\n", {}, "set_env after a node"),
    ("launch:\n- set_env: {name: A}\n", {}, "missing value"),
    ("launch:\n- node: {pkg: p, exec: e, env: [A=b]}\n", {}, "each env is a mapping"),
    ("launch:\n- node: {pkg: p, exec: e, env: [{name: A}]}\n", {}, "missing value"),
])
def test_bad_files_and_arguments_are_refused_in_one_line(tmp_path, monkeypatch, text, args, message):
    monkeypatch.delenv("CIML_UNSET", raising=False)
    path = _write(tmp_path, text)
    with pytest.raises(lf.LaunchFileError) as err:
        lf.load(path, args, find_share=_share)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_argument_syntax():
    assert lf.parse_arguments(["a:=1", "b:=", "c:=x:=y"]) == {"a": "1", "b": "", "c": "x:=y"}
    for bad in ("a=1", ":=1", "1a:=2"):
        with pytest.raises(lf.LaunchFileError):
            lf.parse_arguments([bad])


# --- the runner, with stand-in executables (shell scripts; no ROS) ---------------------------------


def test_set_env_reaches_every_process_and_a_node_env_its_own(tmp_path, monkeypatch):
    """`set_env` holds for every process, a node's `env` over it for that node's process only
    (as ros2 launch applies them); an argument overrides either."""
    _fake_package(tmp_path, {"env": 'echo "$1 transports=$FASTDDS_BUILTIN_TRANSPORTS"\n'})
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    monkeypatch.setenv("FASTDDS_BUILTIN_TRANSPORTS", "SHM")  # the caller's own setting, overridden by the file
    path = _write(tmp_path, """
        launch:
        - arg: {name: t, default: UDPv4}
        - arg: {name: u, default: LARGE_DATA}
        - set_env: {name: FASTDDS_BUILTIN_TRANSPORTS, value: $(var t)}
        - node: {pkg: fake, exec: env, name: a, args: a}
        - node: {pkg: fake, exec: env, name: b, args: b}
        - node: {pkg: fake, exec: env, name: c, args: c, env: [{name: FASTDDS_BUILTIN_TRANSPORTS, value: $(var u)}]}
        """)
    for args, expected in (({}, ("UDPv4", "LARGE_DATA")), ({"t": "DEFAULT", "u": "SHM"}, ("DEFAULT", "SHM"))):
        out = tmp_path / "out.txt"
        with open(out, "w") as f:
            launcher = Launcher(lf.load(path, args), out=f, stop_timeout=10.0)
            launcher.start()
            deadline = time.monotonic() + 10
            while launcher.poll() and time.monotonic() < deadline:
                time.sleep(0.05)
            launcher.stop()
        lines = sorted(line.split("] ", 1)[1] for line in out.read_text().splitlines() if "transports=" in line)
        assert lines == [f"a transports={expected[0]}", f"b transports={expected[0]}",
                         f"c transports={expected[1]}"], lines
    # one process has one environment: a container's nodes must agree on theirs
    desc = lf.load(path, {})
    with pytest.raises(lf.LaunchFileError, match="nodes of both have different env"):
        lf.process_plan(lf.LaunchDescription(desc.path, desc.arguments, desc.nodes,
                                             {**desc.configuration, "containers": "both:a,c"}, desc.declared_nodes))
    assert [p.environment for p in lf.process_plan(lf.LaunchDescription(
        desc.path, desc.arguments, desc.nodes, {"containers": "ab:a,b"}, desc.declared_nodes))] == \
        [{}, {"FASTDDS_BUILTIN_TRANSPORTS": "LARGE_DATA"}]


def _fake_package(tmp_path, scripts: dict[str, str]) -> None:
    """An ament prefix with package 'fake' whose executables are the given shell scripts."""
    prefix = tmp_path / "prefix"
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (prefix / "share" / "ament_index" / "resource_index" / "packages" / "fake").write_text("")
    (prefix / "lib" / "fake").mkdir(parents=True)
    for name, body in scripts.items():
        exe = prefix / "lib" / "fake" / name
        exe.write_text("#!/bin/sh\n" + body)
        exe.chmod(0o755)


TRAP_INT = 'echo "up $*"; trap \'echo "got INT"; exit 0\' INT; while true; do sleep 0.05; done\n'


def test_runner_forwards_sigint_and_reports_rc(tmp_path, monkeypatch):
    _fake_package(tmp_path, {"good": TRAP_INT, "dies": "echo bye; exit 3\n",
                             "stubborn": "trap '' INT; while true; do sleep 0.05; done\n"})
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    monkeypatch.delenv("ROS_AUTOMATIC_DISCOVERY_RANGE", raising=False)
    path = _write(tmp_path, """
        launch:
        - node: {pkg: fake, exec: good, name: a, param: [{name: k, value: "2.5"}]}
        - node: {pkg: fake, exec: dies, name: b}
        """)
    out = tmp_path / "out.txt"
    with open(out, "w") as f:
        launcher = Launcher(lf.load(path), out=f, log_dir=str(tmp_path / "logs"), stop_timeout=10.0)
        assert launcher.env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
        launcher.start()
        deadline = time.monotonic() + 10
        while launcher.poll() and time.monotonic() < deadline and launcher.nodes[1].returncode is None:
            time.sleep(0.05)
        assert launcher.nodes[1].returncode == 3
        assert launcher.nodes[0].returncode is None  # the other node keeps running
        time.sleep(0.3)
        assert launcher.stop() == 1  # one node did not exit cleanly
    text = out.read_text()
    assert "[a] up --ros-args -r __node:=a -p k:=2.5" in text
    assert "[b] bye" in text and "b (pid" in text and "died with exit code 3" in text
    assert "[a] got INT" in text and "a (pid" in text and "exited cleanly" in text
    assert (tmp_path / "logs" / "a.log").read_text().startswith("up ")

    path = _write(tmp_path, "launch:\n- node: {pkg: fake, exec: good, name: a}\n"
                            "- node: {pkg: fake, exec: stubborn, name: s}\n")
    with open(out, "w") as f:
        launcher = Launcher(lf.load(path), out=f, stop_timeout=0.5)
        launcher.start()
        time.sleep(0.5)
        t0 = time.monotonic()
        rc = launcher.stop()
        assert time.monotonic() - t0 < 5.0
    assert rc == 1 and launcher.nodes[0].returncode == 0 and launcher.nodes[1].returncode == -signal.SIGTERM
    assert "still running 0.5 s after SIGINT: SIGTERM" in out.read_text()


def test_ciml_launch_process_exits_0_on_sigint(tmp_path):
    _fake_package(tmp_path, {"good": TRAP_INT})
    path = _write(tmp_path, "launch:\n- node: {pkg: fake, exec: good, name: a}\n"
                            "- node: {pkg: fake, exec: good, name: b}\n")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(tmp_path / "prefix"))
    proc = subprocess.Popen([os.path.join(sys.prefix, "bin", "ciml"), "launch", path], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        while sum("] up" in ln for ln in lines) < 2:
            line = proc.stdout.readline()
            assert line, "".join(lines)
            lines.append(line)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert out.count("got INT") == 2 and "all 2 processes exited cleanly" in out
    with pytest.raises(lf.LaunchFileError, match="executable 'nope' not found"):
        os.environ["AMENT_PREFIX_PATH"], old = str(tmp_path / "prefix"), os.environ.get("AMENT_PREFIX_PATH")
        try:
            Launcher(lf.load(_write(tmp_path, "launch:\n- node: {pkg: fake, exec: nope}\n")))
        finally:
            if old is None:
                os.environ.pop("AMENT_PREFIX_PATH")
            else:
                os.environ["AMENT_PREFIX_PATH"] = old


def _alive(pid: int) -> bool:
    """A process that runs (a zombie left to a parent that does not reap is not running)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_a_killed_ciml_launch_leaves_no_node_running(tmp_path):
    """kill -9 of `ciml launch` (no chance to forward a signal): every node it started ends
    anyway, a stubborn one too (SIGTERM from the kernel, PR_SET_PDEATHSIG)."""
    _fake_package(tmp_path, {"good": TRAP_INT, "stubborn": "echo up; trap '' INT; while true; do sleep 0.05; done\n"})
    path = _write(tmp_path, "launch:\n- node: {pkg: fake, exec: good, name: a}\n"
                            "- node: {pkg: fake, exec: stubborn, name: s}\n")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(tmp_path / "prefix"))
    proc = subprocess.Popen([os.path.join(sys.prefix, "bin", "ciml"), "launch", path], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        pids: list[int] = []
        while sum("] up" in ln for ln in lines) < 2 or len(pids) < 2:
            line = proc.stdout.readline()
            assert line, "".join(lines)
            lines.append(line)
            pids += [int(m) for m in re.findall(r"started \w+ \(pid (\d+)\)", line)]
        assert all(_alive(p) for p in pids), lines
    finally:
        proc.kill()
        proc.communicate()
    deadline = time.monotonic() + 10.0
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in pids), [p for p in pids if _alive(p)]


def test_nodes_started_from_a_thread_that_ends_keep_running(tmp_path, monkeypatch):
    """PR_SET_PDEATHSIG fires when the *thread* that forked the node ends: a launcher started from
    a short-lived thread (a test runner's, a GUI's) must not see its nodes killed with it."""
    import threading

    _fake_package(tmp_path, {"good": TRAP_INT})
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    out = tmp_path / "out.txt"
    with open(out, "w") as f:
        launcher = Launcher(lf.load(_write(tmp_path, "launch:\n- node: {pkg: fake, exec: good, name: a}\n")), out=f)
        starter = threading.Thread(target=launcher.start)
        starter.start()
        starter.join()
        deadline = time.monotonic() + 10
        while "[a] up" not in out.read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        assert launcher.nodes[0].proc.poll() is None, out.read_text()
        assert launcher.stop() == 0
    assert "[a] got INT" in out.read_text()


def test_containers_argument_composes_nodes_in_one_process_each(tmp_path, monkeypatch):
    """`containers:=NAME:a,b ...`: one ciml_container process per group with each node's own
    arguments, the other nodes alone, a node switched off by its condition left out; errors
    in one line."""
    _fake_package(tmp_path, {"good": TRAP_INT})
    (tmp_path / "prefix" / "lib" / "ciml_learning").mkdir(parents=True)
    (tmp_path / "prefix" / "share" / "ament_index" / "resource_index" / "packages" / "ciml_learning").write_text("")
    container = tmp_path / "prefix" / "lib" / "ciml_learning" / "ciml_container"
    container.write_text("#!/bin/sh\n" + TRAP_INT)
    container.chmod(0o755)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    text = """
        launch:
        - arg: {name: containers, default: "hot:a,b"}
        - arg: {name: with_c, default: "true"}
        - node: {pkg: fake, exec: good, name: a, param: [{name: k, value: "1.5"}]}
        - node: {pkg: fake, exec: good, name: b}
        - node: {pkg: fake, exec: good, name: c, if: $(var with_c)}
        - node: {pkg: fake, exec: good, name: d}
        """
    desc = lf.load(_write(tmp_path, text))
    plan = lf.process_plan(desc)
    assert [(p.label, [n.label for n in p.nodes], p.composed) for p in plan] == [
        ("hot", ["a", "b"], True), ("c", ["c"], False), ("d", ["d"], False)]
    out = tmp_path / "out.txt"
    with open(out, "w") as f:
        launcher = Launcher(desc, out=f, stop_timeout=10.0)
        assert launcher.cmds[0] == [str(container), "--node", "fake", "good", "--ros-args", "-r", "__node:=a",
                                    "-p", "k:=1.5", "--node", "fake", "good", "--ros-args", "-r", "__node:=b"]
        launcher.start()
        time.sleep(0.5)
        assert launcher.stop() == 0
    assert "all 3 processes exited cleanly" in out.read_text()
    # a node switched off by its condition may stay listed; no containers → one process per node
    plan = lf.process_plan(lf.load(_write(tmp_path, text.replace('"hot:a,b"', '"hot:a,c"')), {"with_c": "false"}))
    assert [p.label for p in plan] == ["hot", "b", "d"]
    assert [p.label for p in lf.process_plan(lf.load(_write(tmp_path, text), {"containers": ""}))] == list("abcd")
    for spec, message in [("hot:a,x", "no node named x"), ("hot:a two:a", "'a' is in both hot and two"),
                          ("hot", "is not NAME:node"), ("a:b", None)]:
        desc = lf.load(_write(tmp_path, text), {"containers": spec})
        if message is None:  # a container named like a lone node
            with pytest.raises(lf.LaunchFileError, match="process name.* used twice"):
                Launcher(desc)
        else:
            with pytest.raises(lf.LaunchFileError, match=message):
                lf.process_plan(desc)


def test_launch_prefix_runs_before_the_executable(tmp_path, monkeypatch):
    _fake_package(tmp_path, {"good": TRAP_INT})
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    text = """
        launch:
        - arg: {name: containers, default: ""}
        - node: {pkg: fake, exec: good, name: a, launch-prefix: "nice -n 5"}
        - node: {pkg: fake, exec: good, name: b}
        """
    launcher = Launcher(lf.load(_write(tmp_path, text)))
    assert launcher.cmds[0][:3] == ["nice", "-n", "5"] and launcher.cmds[1][0].endswith("/fake/good")
    with pytest.raises(lf.LaunchFileError, match="different launch-prefix"):
        lf.process_plan(lf.load(_write(tmp_path, text), {"containers": "c:a,b"}))


def test_container_command_line_and_node_lookup():
    from ciml_learning.ros import container

    assert container.parse_command_line(["--node", "p", "a", "--ros-args", "-p", "x:=1", "--node", "q", "b"]) == [
        ("p", "a", ["--ros-args", "-p", "x:=1"]), ("q", "b", [])]
    for bad in ([], ["a"], ["--node", "p"], ["--node", "p", "a", "--node"]):
        with pytest.raises(container.ContainerError):
            container.parse_command_line(bad)
    assert container.node_class("ciml_learning", "state_filter").__name__ == "StateFilterNode"
    with pytest.raises(container.ContainerError, match="belongs to ciml_learning"):
        container.node_class("ciml_sim", "state_filter")
    with pytest.raises(container.ContainerError, match="no composable node 'nope'"):
        container.node_class("ciml_sim", "nope")


# --- the live benchmarks' measurement helpers (ciml_learning.ros.graph_probe) -------------------------


def test_period_statistics_of_receipt_times():
    import numpy as np

    from ciml_learning.ros.graph_probe import period_stats

    rng = np.random.default_rng(0)
    t = np.cumsum(np.full(2500, 0.004) + rng.normal(0, 1e-4, 2500))
    t[1000:] += 0.05  # one 54 ms gap
    s = period_stats(t, 250.0)
    assert s["messages"] == 2500
    assert abs(s["rate_hz"] - 2499 / (t[-1] - t[0])) < 0.1 and s["rate_error_pct"] < 0
    assert 3.9 < s["period_p50_ms"] < 4.1 and 53.0 < s["period_max_ms"] < 55.0
    assert s["jitter_p99_ms"] < 0.5  # one gap in 2500 periods is beyond the 99th percentile
    assert period_stats(t[:2], 250.0) == {"messages": 2}


def test_feedback_effort_is_the_pd_part_plus_feedback_linearisation():
    import numpy as np

    from ciml_learning.core.conversions import TorqueCommandArrays
    from ciml_learning.ros.graph_probe import feedback_effort

    n = 12
    kp, kd = np.full(n, 300.0), np.full(n, 8.0)
    q_t, qd_t, lin = np.full(n, 0.1), np.full(n, 0.5), np.arange(n, dtype=float)
    cmd = TorqueCommandArrays(0, np.full(n, 99.0), lin, q_t, qd_t, kp, kd)  # u_ff is not feedback
    q, qd = np.zeros(n), np.zeros(n)
    expected = np.linalg.norm(300.0 * 0.1 + 8.0 * 0.5 + lin)
    assert abs(feedback_effort(cmd, q, qd) - expected) < 1e-9
    assert feedback_effort(cmd, q_t, qd_t) == np.linalg.norm(lin)


def test_process_memory_and_cpu_readers():
    from ciml_learning.ros.graph_probe import cpu_seconds
    from ciml_learning.ros.realtime import rss_mb

    assert rss_mb(os.getpid()) > 10.0 and cpu_seconds(os.getpid()) > 0.0
    dead = subprocess.Popen(["true"])
    dead.wait()
    assert rss_mb(dead.pid) is None and cpu_seconds(dead.pid) is None
