"""ROS conventions a user expects of every CIML node (issue 18 item 5): QoS a default
subscriber matches, /diagnostics that recover, parameters from one schema (reconfigurable or
refused), one-line errors for bad parameters, clean exits on signals, /tf and
/robot_description, shipped layouts, the venv as an ament prefix, /gap_diagnosis."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from rosutil import BIN, Listener, start_node, stop

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# --- /diagnostics that recover -------------------------------------------------------------------


@pytest.fixture
def node_in_private_context():
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("health_test", context=ctx)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def test_health_condition_raised_then_cleared_returns_to_ok(node_in_private_context):
    from ciml_learning.ros.ros_common import ERROR, OK, WARN, Health

    health = Health(node_in_private_context, event_hold=0.2)
    health.set(OK, "torque control")
    assert health.status().level == bytes([OK]) and health.status().message == "torque control"
    health.condition("stale_state", True, WARN, "base state stale: damping")
    health.condition("qp", True, ERROR, "QP infeasible")
    st = health.status()
    assert st.level == bytes([ERROR]) and st.message == "QP infeasible"  # the worst active condition
    health.condition("qp", False)
    assert health.status().level == bytes([WARN]) and health.status().message == "base state stale: damping"
    health.condition("stale_state", False)
    assert health.status().level == bytes([OK]) and health.status().message == "torque control"
    # a warned event is a condition for `event_hold` seconds after its last occurrence; counts stay
    health.count("rejected_commands", "command rejected: NaN")
    health.count("rejected_commands", "command rejected: NaN")
    assert health.status().level == bytes([WARN]) and "NaN" in health.status().message
    time.sleep(0.3)
    st = health.status()
    assert st.level == bytes([OK]) and st.message == "torque control"
    assert {kv.key: kv.value for kv in st.values} == {"rejected_commands": "2"}
    # the mode itself can be a warning (e.g. the bridge holding the standing pose)
    health.set(WARN, "holding the standing pose")
    assert health.status().level == bytes([WARN])
    health.set(OK, "torque control")
    assert health.status().level == bytes([OK])


def test_health_publishes_at_the_first_spin_then_once_a_period(node_in_private_context):
    """A monitor sees a node up as soon as it spins, not a publish period later."""
    from ciml_learning.ros.executor import DirectExecutor
    from ciml_learning.ros.ros_common import PUBLISH_PERIOD, Health

    node = node_in_private_context
    health = Health(node)
    sent: list[float] = []
    publish = health._pub.publish
    health._pub.publish = lambda msg: (sent.append(time.monotonic()), publish(msg))
    executor = DirectExecutor(context=node.context)
    executor.add_node(node)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 0.3:
        executor.spin_once(timeout_sec=0.05)
    # one message, well before the 1 Hz timer's first (a second after the node was made)
    assert len(sent) == 1 and sent[0] - t0 < 0.5 * PUBLISH_PERIOD, [t - t0 for t in sent]
    while time.monotonic() - t0 < PUBLISH_PERIOD + 0.3:
        executor.spin_once(timeout_sec=0.05)
    assert len(sent) == 2, [t - t0 for t in sent]  # then the 1 Hz timer alone
    executor.shutdown(timeout_sec=0)


def start(exe: str, module: str, *ros_args: str) -> subprocess.Popen:
    """A node by its console script (or by its module before the venv was re-installed), with
    faulthandler on: a hung node shows its stacks on SIGABRT."""
    exe_path = os.path.join(BIN, exe)
    cmd = [exe_path] if os.path.exists(exe_path) else [sys.executable, "-m", module]
    cmd += ["--ros-args", *ros_args] if ros_args else []
    env = {**os.environ, "PYTHONFAULTHANDLER": "1"}
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


# --- /tf and /robot_description ------------------------------------------------------------------


def _compose(chain):
    import pinocchio as pin

    T = pin.SE3.Identity()
    for tf in chain:
        t, r = tf.transform.translation, tf.transform.rotation
        T = T * pin.XYZQUATToSE3([t.x, t.y, t.z, r.x, r.y, r.z, r.w])
    return T


@pytest.mark.ros
def test_state_publisher_tf_matches_pinocchio_fk():
    import numpy as np
    import pinocchio as pin
    from nav_msgs.msg import Odometry
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from ciml_learning.core import conversions as cv
    from ciml_learning.core.robot import load_robot

    robot = load_robot()
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    listener = Listener({"/tf": TFMessage, "/tf_static": TFMessage, "/robot_description": String},
                        qos={"/tf_static": latched, "/robot_description": latched})
    pub_j = listener.node.create_publisher(JointState, "/joint_states", 10)
    pub_b = listener.node.create_publisher(Odometry, "/base_state", 10)
    rng = np.random.default_rng(3)
    q_j = robot.standing_joints + rng.uniform(-0.3, 0.3, robot.n_joints)
    position, quat = np.array([0.4, -0.2, 0.6]), rng.normal(size=4)
    quat /= np.linalg.norm(quat)
    node = start("state_publisher", "ciml_learning.nodes.state_publisher")
    try:
        def sent_and_received():
            ns = time.time_ns()
            pub_j.publish(cv.joint_state_msg(robot, ns, q_j, np.zeros(robot.n_joints), np.zeros(robot.n_joints)))
            pub_b.publish(cv.odometry_msg(ns, position, quat, np.zeros(3), np.zeros(3)))
            frames = {tf.child_frame_id for m in listener.messages["/tf"] for tf in m.transforms}
            return "base_link" in frames and "lf_lowerleg" in frames and listener.messages["/tf_static"]
        assert listener.wait_for(sent_and_received, timeout=30), stop(node)
        assert listener.wait_for(lambda: listener.messages["/robot_description"], 5)
    finally:
        log = stop(node)
        listener.close()
    assert "Traceback" not in log, log
    urdf = listener.messages["/robot_description"][-1].data
    assert urdf.startswith("<?xml") or "<robot" in urdf
    latest = {}
    for m in listener.messages["/tf"] + listener.messages["/tf_static"]:
        for tf in m.transforms:
            latest[tf.child_frame_id] = tf
    assert latest["base_link"].header.frame_id == "world"  # the bridge's odometry frame
    # walk lf_foot → root through the parents, then compose root → lf_foot
    chain, frame = [], "lf_foot"
    while frame in latest:
        chain.append(latest[frame])
        frame = latest[frame].header.frame_id
    assert frame == "world"
    T = _compose(reversed(chain))
    q = np.concatenate([position, quat, q_j])
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    expected = data.oMf[robot.model.getFrameId("lf_foot")]
    assert np.allclose(T.translation, expected.translation, atol=1e-6), (T.translation, expected.translation)
    assert np.allclose(T.rotation, expected.rotation, atol=1e-6)


# --- QoS: a default-QoS reader (a dashboard) receives every topic; clean exits on signals ----------

NODES = {  # executable -> (module, ros args of a small live graph)
    "mujoco_bridge": ("ciml_sim.bridge_node", ()),
    "reference_generator": ("ciml_control.nodes.reference_generator", ("-p", "motion:=stand")),
    "id_controller": ("ciml_control.nodes.id_controller", ()),
    "state_filter": ("ciml_learning.nodes.state_filter", ()),
    "error_extractor": ("ciml_learning.nodes.error_extractor", ()),
    "model_server": ("ciml_learning.nodes.model_server", ()),
    "online_learner": ("ciml_learning.nodes.online_learner", ()),
    "state_publisher": ("ciml_learning.nodes.state_publisher", ()),
}


def _params_file(exe: str) -> tuple[str, ...]:
    """--params-file of the node's shipped config/<node>.yaml (generated from its schema)."""
    for pkg in ("ciml_sim", "ciml_control", "ciml_learning"):
        path = os.path.join(ROOT, pkg, "config", f"{exe}.yaml")
        if os.path.exists(path):
            return ("--params-file", path)
    return ()


def _start_graph(tmp_path, names=tuple(NODES)) -> dict[str, subprocess.Popen]:
    """The nodes with their shipped deployment files (so those are valid for rcl too)."""
    procs = {}
    for exe in names:
        module, args = NODES[exe]
        args = (*_params_file(exe), *args)
        if exe == "online_learner":  # snapshots into the test's folder
            args = (*args, "-p", f"model_dir:={tmp_path / 'online'}")
        procs[exe] = start(exe, module, *args)
    return procs


EXIT_TIMEOUT = 60.0
"""[s] for every node to exit after a signal: ~2-10 s on this 2-core machine, more under the test
suite's own load (interpreter teardown of numba/MuJoCo/rclpy objects); a hang never ends."""


def _signal_all(procs: dict[str, subprocess.Popen], sig: int) -> dict[str, tuple[int, str]]:
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(sig)
    out = {}
    deadline = time.monotonic() + EXIT_TIMEOUT
    for exe, p in procs.items():
        try:
            log, _ = p.communicate(timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:  # hung: SIGABRT makes faulthandler dump every thread's stack
            p.send_signal(signal.SIGABRT)
            try:
                log, _ = p.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                log, _ = p.communicate()
            log = (log or "") + f"\n[test] still running {EXIT_TIMEOUT:g} s after the signal"
        out[exe] = (p.returncode, log or "")
    return out


def _assert_clean(results: dict[str, tuple[int, str]], what: str) -> None:
    bad = {exe: (rc, log[-1500:]) for exe, (rc, log) in results.items() if rc != 0 or "Traceback" in log}
    assert not bad, f"{what}: {bad}"


@pytest.mark.ros
@pytest.mark.slow
def test_default_qos_reader_receives_every_topic_and_nodes_exit_cleanly(tmp_path):
    from ciml_msgs.msg import ContactState, ModelError, RobotReference, RobotState, TorqueCommand
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from tf2_msgs.msg import TFMessage

    from ciml_learning.core import topics

    wanted = {topics.JOINT_STATES: JointState, topics.BASE_STATE: Odometry, topics.CONTACT_STATE: ContactState,
              topics.CLOCK: Clock, topics.TORQUE_COMMAND: TorqueCommand, topics.REFERENCE: RobotReference,
              topics.FILTERED_STATE: RobotState, topics.MODEL_ERROR_MEASURED: ModelError,
              topics.MODEL_ERROR_PREDICTED: ModelError, topics.DIAGNOSTICS: DiagnosticArray, topics.TF: TFMessage}
    default = QoSProfile(depth=10)  # what `ros2 topic echo`, Foxglove and PlotJuggler use
    assert default.reliability.name == "RELIABLE" and default.durability.name == "VOLATILE"
    listener = Listener(wanted, qos={t: default for t in wanted})
    procs = _start_graph(tmp_path, tuple(n for n in NODES if n != "online_learner"))  # it publishes none of these
    try:
        ok = listener.wait_for(lambda: all(len(listener.messages[t]) >= 3 for t in wanted), timeout=120)
        missing = {t: len(listener.messages[t]) for t in wanted if len(listener.messages[t]) < 3}
    finally:
        results = _signal_all(procs, signal.SIGINT)
        listener.close()
    assert ok, f"topics a default-QoS reader did not receive: {missing}; logs: " + str(
        {k: v[1][-800:] for k, v in results.items()})
    _assert_clean(results, "SIGINT of the running graph")


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize("sig,after", [(signal.SIGINT, 0.0), (signal.SIGTERM, 0.0), (signal.SIGTERM, 3.0)],
                         ids=["sigint-starting", "sigterm-starting", "sigterm-running"])
def test_every_node_exits_cleanly_on_signals(tmp_path, sig, after):
    """The mechanism (ros_common.run_node), three times per node: as soon as the node is on the
    graph (the signal races its construction and first spin) and while the graph runs.
    (Before rclpy.init, i.e. while Python imports the node's modules, a signal has its default
    effect; that is not covered here.)"""
    listener = Listener({})
    procs = _start_graph(tmp_path)
    try:
        up = listener.wait_for(lambda: set(NODES) <= set(listener.node.get_node_names()), timeout=90)
        names = listener.node.get_node_names()
    finally:
        listener.close()
    time.sleep(after)
    results = _signal_all(procs, sig)
    assert up, f"nodes not on the graph after 90 s: {set(NODES) - set(names)}"
    _assert_clean(results, f"{signal.Signals(sig).name} {after} s after all nodes were up")


@pytest.mark.ros
@pytest.mark.slow
def test_idle_node_sees_the_signal_itself_and_exits_0():
    """A node with nothing to wake its executor (no traffic; its timers on simulation time and
    no /clock) still sees SIGINT and SIGTERM (ros_common.run_nodes: its own handler, waits of
    at most SIGNAL_POLL_PERIOD) and shuts down itself: status 0, no traceback, and not through
    the watchdog that ends a shutdown stuck for SHUTDOWN_GRACE. Five rounds per signal."""
    listener = Listener({})
    try:
        for k in range(10):
            sig = (signal.SIGINT, signal.SIGTERM)[k % 2]
            name = f"idle_extractor_{k}"
            proc = start_node("error_extractor", "-r", f"__node:={name}", "-p", "use_sim_time:=true")
            up = listener.wait_for(lambda: name in listener.node.get_node_names(), timeout=90)
            time.sleep(0.5)
            results = _signal_all({name: proc}, sig)
            assert up, f"{name} not on the graph after 90 s: {results[name][1][-800:]}"
            _assert_clean(results, f"{signal.Signals(sig).name} of an idle node")
            assert "shutdown not finished" not in results[name][1], results[name][1][-1500:]
    finally:
        listener.close()


# --- bad parameters: one logged line, non-zero exit ------------------------------------------------

BAD = {  # executable -> a numeric parameter
    "mujoco_bridge": "publish_rate", "reference_generator": "rate", "id_controller": "rate",
    "state_filter": "rate", "error_extractor": "gamma", "model_server": "swap_check_period",
    "online_learner": "snapshot_period", "state_publisher": "publish_rate",
}


@pytest.mark.ros
@pytest.mark.parametrize("value", ["abc", "-5.0"], ids=["wrong-type", "out-of-range"])
def test_bad_parameter_is_one_line_and_exit_1(value):
    procs = {exe: start(exe, NODES[exe][0], "-p", f"{param}:={value}") for exe, param in BAD.items()}
    results = {}
    for exe, p in procs.items():
        try:
            log, _ = p.communicate(timeout=180)  # 8 nodes importing at once on 2 cores
        except subprocess.TimeoutExpired:
            p.kill()
            log, _ = p.communicate()
        results[exe] = (p.returncode, [line for line in (log or "").splitlines() if line.strip()])
    for exe, (rc, lines) in results.items():
        assert rc == 1 and len(lines) == 1 and "Traceback" not in lines[0], (exe, rc, lines)
        assert BAD[exe] in lines[0], (exe, lines)


# --- the venv as an ament prefix ---------------------------------------------------------------


def test_sourcing_setup_bash_makes_the_venv_an_ament_prefix():
    setup = os.path.join(sys.prefix, "setup.bash")
    assert os.path.isfile(setup), "run `make install` (tools/ament_layout.py writes .venv/setup.bash)"
    probe = (
        "import json, os\n"
        "from importlib.metadata import distribution\n"
        "from ament_index_python.packages import get_package_prefix, get_package_share_directory\n"
        "out = {}\n"
        "for pkg in ('ciml_learning', 'ciml_control', 'ciml_sim'):\n"
        "    prefix = get_package_prefix(pkg)\n"
        "    exes = sorted(e.name for e in distribution(pkg).entry_points if e.group == 'console_scripts')\n"
        "    runnable = [e for e in exes if os.access(os.path.join(prefix, 'lib', pkg, e), os.X_OK)]\n"
        "    out[pkg] = dict(prefix=prefix, exes=exes, runnable=runnable,\n"
        "                    share=os.path.isfile(os.path.join(get_package_share_directory(pkg), 'package.xml')))\n"
        "print(json.dumps(out))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH")}
    env["PATH"] = "/usr/bin:/bin"  # the venv's python must come from setup.bash
    res = subprocess.run(["bash", "-c", f'source "{setup}" && python -c "$PROBE"'], env={**env, "PROBE": probe},
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr[-2000:]
    import json

    found = json.loads(res.stdout.strip().splitlines()[-1])
    for pkg, info in found.items():
        assert os.path.realpath(info["prefix"]) == os.path.realpath(sys.prefix), (pkg, info)
        assert info["share"] and info["exes"] and info["runnable"] == info["exes"], (pkg, info)
    assert "mujoco_bridge" in found["ciml_sim"]["runnable"] and "id_controller" in found["ciml_control"]["runnable"]
    # without it, the lookup fails (the test above is not vacuous)
    res = subprocess.run([sys.executable, "-c", "from ament_index_python.packages import get_package_prefix as g; "
                          "g('ciml_sim')"], env=env, capture_output=True, text=True, timeout=60)
    assert res.returncode != 0


@pytest.mark.slow
def test_vendored_tf2_msgs_is_built_unless_the_install_prefix_has_it(tmp_path):
    """ciml_msgs' CMake (as tools/install.sh runs it) builds the vendored tf2_msgs into its install
    prefix unless that prefix has one: a tf2_msgs that CMake finds elsewhere — here this venv's,
    for a new prefix — does not count, as the new prefix's Python cannot import it (a fresh clone
    installed from a shell with another venv activated lost /tf so)."""
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix, CMAKE_PREFIX_PATH=sys.prefix,
               PATH=f"{os.path.join(sys.prefix, 'bin')}:{os.environ['PATH']}")
    assert os.path.isdir(os.path.join(sys.prefix, "share", "tf2_msgs", "cmake"))
    for prefix, vendored in ((tmp_path / "prefix", True), (sys.prefix, False)):
        build = tmp_path / f"build_{vendored}"
        build.mkdir()
        res = subprocess.run(["cmake", os.path.join(ROOT, "ciml_msgs"), f"-DCMAKE_INSTALL_PREFIX={prefix}",
                              f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF"],
                             cwd=build, env=env, capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
        assert (build / "install_vendor_tf2_msgs.cmake").exists() == vendored, (prefix, res.stdout[-1500:])


# --- shipped layouts and the diagnostic aggregator -------------------------------------------------

CONFIG = os.path.join(ROOT, "ciml_learning", "config")


def test_foxglove_layout_parses_and_plots_named_fields_of_existing_topics():
    import json
    import re

    from ciml_learning.core import topics
    from ciml_learning.core.robot import load_robot

    robot = load_robot()
    with open(os.path.join(CONFIG, "layouts", "ciml_foxglove.json"), encoding="utf-8") as f:
        layout = json.load(f)
    panels = layout["configById"]

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)  # every panel placed, none dangling
    three_d = next(v for k, v in panels.items() if k.startswith("3D!"))
    urdf = [layer for layer in three_d["layers"].values() if layer["layerId"] == "foxglove.Urdf"]
    assert urdf and urdf[0]["topic"] == topics.ROBOT_DESCRIPTION and topics.TF in three_d["topics"]
    names = {"rbd_error": robot.rbd_error_names, "actuation_error": robot.joint_names}
    plotted = set()
    for key, panel in panels.items():
        if key.startswith("Plot!"):
            for path in panel["paths"]:
                m = re.fullmatch(r"(/[\w/]+)\.(\w+)\[(\d+)\]", path["value"])
                assert m, path
                topic, field, index = m.group(1), m.group(2), int(m.group(3))
                assert topic in (topics.MODEL_ERROR_MEASURED, topics.MODEL_ERROR_PREDICTED)
                assert path["label"].split()[0] == names[field][index], path  # the label names the field
                plotted.add(topic)
        if key.startswith("Diagnostic"):
            assert panel["topicToRender"] == topics.DIAGNOSTICS
    assert plotted == {topics.MODEL_ERROR_MEASURED, topics.MODEL_ERROR_PREDICTED}


def test_plotjuggler_layout_parses_and_references_existing_topics():
    import re
    from xml.etree import ElementTree

    from ciml_learning.core import topics
    from ciml_learning.core.robot import load_robot

    robot = load_robot()
    root = ElementTree.parse(os.path.join(CONFIG, "layouts", "ciml_plotjuggler.xml")).getroot()
    selected = {t.get("name") for t in root.iter("topic")}
    assert selected and selected <= set(topics.TYPES)
    curves = [c.get("name") for c in root.iter("curve")]
    assert len(curves) >= 4
    sizes = {"rbd_error": len(robot.rbd_error_names), "actuation_error": robot.n_joints}
    for name in curves:
        m = re.fullmatch(r"(/[\w/]+)/(rbd_error|actuation_error)\[(\d+)\]", name)
        assert m and m.group(1) in selected and int(m.group(3)) < sizes[m.group(2)], name


def test_diagnostic_aggregator_covers_every_node_once():
    from importlib.metadata import distribution

    import yaml

    with open(os.path.join(CONFIG, "diagnostic_aggregator.yaml"), encoding="utf-8") as f:
        params = yaml.safe_load(f)["analyzers"]["ros__parameters"]
    analyzers = {k: v for k, v in params.items() if isinstance(v, dict)}
    assert all(a["type"] == "diagnostic_aggregator/GenericAnalyzer" and a["path"] for a in analyzers.values())
    nodes = {name for name in NODES}
    for node in nodes:
        owners = [k for k, a in analyzers.items() if node in a["contains"]]
        assert len(owners) == 1, (node, owners)
    for pkg in ("ciml_learning", "ciml_control", "ciml_sim"):  # every installed node executable is in NODES
        exes = {e.name for e in distribution(pkg).entry_points if e.group == "console_scripts"}
        exes -= {"ciml", "ciml_container"}  # the command line and the container are no nodes
        assert exes <= nodes, exes - nodes


# --- GapDiagnosis published ----------------------------------------------------------------------


@pytest.mark.ros
def test_gap_diagnosis_published_once_and_received_by_a_late_subscriber():
    import threading

    from ciml_msgs.msg import GapDiagnosis
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from ciml_learning.cli.main import build_parser
    from ciml_learning.ros.gap_publisher import gap_diagnosis_fields, publish_gap_diagnosis

    args = build_parser().parse_args(["diagnose", "--bag", "b", "--out", "d", "--publish"])
    assert args.publish == 5.0
    result = {  # the diagnosis.json fields the summary reads
        "localization": [{"dimension": "lf_kfe_joint", "rms_error": 3.2, "share": 0.6},
                         {"dimension": "base_fz", "rms_error": 12.0, "share": 0.3}],
        "effects": [{"type": "joint_coulomb_friction", "joint": "lf_kfe_joint", "share": 0.55},
                    {"type": "payload", "link": "trunk", "share": 0.25}],
        "unexplained_share": 0.2,
        "shrink": {"heldout_rms_nominal": 2.5, "heldout_rms_with_effects": 1.0, "ratio": 0.6},
    }
    fields = gap_diagnosis_fields(result)
    assert fields["effect_locations"] == ["lf_kfe_joint", "trunk"] and fields["shrink_ratio"] == 0.6
    thread = threading.Thread(target=publish_gap_diagnosis, args=(result, 8.0), daemon=True)
    thread.start()
    time.sleep(2.0)  # the subscriber joins after the message was published: transient local delivers it
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    listener = Listener({"/gap_diagnosis": GapDiagnosis}, qos={"/gap_diagnosis": latched})
    try:
        assert listener.wait_for(lambda: listener.messages["/gap_diagnosis"], timeout=5)
    finally:
        listener.close()
        thread.join(timeout=10)
    msgs = listener.messages["/gap_diagnosis"]
    assert len(msgs) == 1
    m = msgs[0]
    assert list(m.dimension_names) == ["lf_kfe_joint", "base_fz"] and list(m.dimension_share) == [0.6, 0.3]
    assert list(m.effect_types) == ["joint_coulomb_friction", "payload"] and list(m.effect_share) == [0.55, 0.25]
    assert (m.unexplained_share, m.heldout_rms_nominal, m.heldout_rms_with_effects) == (0.2, 2.5, 1.0)


# --- one parameter schema per node: declared from it, reconfigurable or refused ----------------------

MIGRATED = {  # node class -> its schema (ciml_*/node_params.py)
    "ciml_sim.bridge_node:MujocoBridge": "ciml_sim.node_params:MUJOCO_BRIDGE",
    "ciml_control.nodes.reference_generator:ReferenceGeneratorNode": "ciml_control.node_params:REFERENCE_GENERATOR",
    "ciml_learning.nodes.error_extractor:ErrorExtractorNode": "ciml_learning.ros.node_params:ERROR_EXTRACTOR",
    "ciml_learning.nodes.state_publisher:StatePublisherNode": "ciml_learning.ros.node_params:STATE_PUBLISHER",
    "ciml_learning.nodes.model_server:ModelServerNode": "ciml_learning.ros.node_params:MODEL_SERVER",
    "ciml_learning.nodes.state_filter:StateFilterNode": "ciml_learning.ros.node_params:STATE_FILTER",
    "ciml_control.nodes.id_controller:IdControllerNode": "ciml_control.node_params:ID_CONTROLLER",
    "ciml_learning.nodes.online_learner:OnlineLearnerNode": "ciml_learning.ros.node_params:ONLINE_LEARNER",
}


def _load(spec: str):
    import importlib

    module, name = spec.split(":")
    return getattr(importlib.import_module(module), name)


def _other_value(p):
    """A valid value different from the default."""
    if isinstance(p.default, bool):
        return not p.default
    if p.choices and len(p.choices) > 1:
        return next(c for c in p.choices if c != p.default)
    if isinstance(p.default, str):  # (a single choice: read-only, refused whatever the value)
        return p.default + "x"
    lo = p.lo if p.lo is not None else p.default - 1
    hi = p.hi if p.hi is not None else p.default + 1
    if isinstance(p.default, int):
        return p.default + 1 if p.default + 1 <= hi else p.default - 1
    return p.default + 0.5 * ((hi if hi > p.default else lo) - p.default)


def test_param_docs_are_generated_from_the_schemas():
    res = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "param_docs.py"), "--check"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


@pytest.mark.ros
@pytest.mark.parametrize("node_spec", sorted(MIGRATED))
def test_every_parameter_is_reconfigurable_or_refused(node_spec):
    import rclpy
    from rclpy.parameter import Parameter

    schema = _load(MIGRATED[node_spec])
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = _load(node_spec)(context=ctx)
        declared = set(node._parameters) - {"use_sim_time", "start_type_description_service"}  # rclpy's own
        assert declared == {p.name for p in schema.params}, "the node declares exactly its schema"
        for p in schema.params:
            desc = node.describe_parameter(p.name)
            assert desc.read_only == p.read_only and desc.description.startswith(p.description)
            result = node.set_parameters([Parameter(p.name, value=_other_value(p))])[0]
            if p.read_only:
                assert not result.successful, p.name  # refused, never "successful and ignored"
                assert node.get_parameter(p.name).value == p.default
            else:
                assert result.successful, (p.name, result.reason)
                assert node.get_parameter(p.name).value == _other_value(p)
                if p.hi is not None and not isinstance(p.default, bool):
                    too_big = p.hi + 1 if isinstance(p.default, int) else p.hi * 2 + 1.0
                    assert not node.set_parameters([Parameter(p.name, value=too_big)])[0].successful
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_runtime_rate_set_changes_the_reference_rate_and_a_read_only_set_is_refused():
    from ciml_msgs.msg import RobotReference
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    listener = Listener({"/reference": RobotReference})
    client = listener.node.create_client(SetParameters, "/reference_generator/set_parameters")
    node = start_node("reference_generator", "--params-file",
                      os.path.join(ROOT, "ciml_control", "config", "reference_generator.yaml"))
    msgs = listener.messages["/reference"]

    def rate_over(seconds: float) -> float:
        n0, t0 = len(msgs), time.monotonic()
        time.sleep(seconds)
        return (len(msgs) - n0) / (time.monotonic() - t0)

    def call(name: str, value: ParameterValue):
        future = client.call_async(SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)]))
        assert listener.wait_for(future.done, 10)
        return future.result().results[0]

    try:
        assert listener.wait_for(lambda: len(msgs) >= 50, timeout=60), stop(node)
        assert client.wait_for_service(timeout_sec=10)
        before = rate_over(2.0)
        res = call("rate", ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=50.0))
        assert res.successful, res.reason
        time.sleep(0.5)
        after = rate_over(3.0)
        refused = call("motion", ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="walk_20"))
        out_of_range = call("rate", ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=-5.0))
        still = rate_over(2.0)
    finally:
        log = stop(node)
        listener.close()
    assert "Traceback" not in log, log
    # 250 Hz nominal, then 50 Hz (a loaded machine delays timers: at most 50 Hz, far below before)
    assert before > 100 and 20 < after < 55 and after < 0.4 * before, (before, after)
    assert not refused.successful and not out_of_range.successful
    assert 20 < still < 55, still
    assert all(m.motion == "trot_35" for m in msgs[-20:])  # the deployment file's motion, unchanged
