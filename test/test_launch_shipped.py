"""The shipped graph, ciml_sim/launch/closed_loop.launch.yaml, read by `ciml launch`
(ciml_learning.ros.launch_file): defaults, arguments, the ros2 launch YAML format, node command
lines, one-line errors. (Moved from ciml_learning/test/test_launch_file.py: the file belongs to
ciml_sim; the launch subset itself is tested there.)"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
import yaml

from ciml_learning.ros import launch_file as lf

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHIPPED = os.path.join(ROOT, "ciml_sim", "launch", "closed_loop.launch.yaml")


def _share(pkg: str) -> str:
    return f"/prefix/share/{pkg}"


def test_shipped_file_defaults_and_arguments():
    desc = lf.load(SHIPPED, {}, find_share=_share)
    names = [n.label for n in desc.nodes]
    assert names == ["mujoco_bridge", "reference_generator", "id_controller", "model_server", "state_filter",
                     "error_extractor", "online_learner", "state_publisher"]
    bridge = dict(desc.nodes[0].parameters)
    assert bridge["scenario"] == "" and bridge["robot"] == "hyq"  # '': the robot's own scenario (hyq: default_gap)
    assert bridge["real_time_factor"] == 1.0 and isinstance(bridge["real_time_factor"], float)
    assert bridge["seed"] == 0 and isinstance(bridge["seed"], int)
    assert dict(desc.nodes[2].parameters)["use_sim_time"] is True

    desc = lf.load(SHIPPED, {"online_learning": "false", "motion": "walk_30", "use_model_error": "False"},
                   find_share=_share)
    assert "online_learner" not in [n.label for n in desc.nodes]
    assert dict(desc.nodes[1].parameters)["motion"] == "walk_30"
    assert dict(desc.nodes[2].parameters)["use_model_error"] is False


def test_robot_argument_reaches_every_node():
    """robot:=go1 (what `ciml --robot go1 launch ...` passes) is every node's `robot` parameter."""
    desc = lf.load(SHIPPED, {"robot": "go1"}, find_share=_share)
    assert {n.label: dict(n.parameters)["robot"] for n in desc.nodes} == {n.label: "go1" for n in desc.nodes}
    assert len(desc.nodes) == 8
    desc = lf.load(SHIPPED, {"effort_command_topic": "/effort_controller/commands", "feedforward_only": "true"},
                   find_share=_share)
    controller = dict(next(n for n in desc.nodes if n.label == "id_controller").parameters)
    assert controller["effort_command_topic"] == "/effort_controller/commands"
    assert controller["feedforward_only"] is True


def test_shipped_file_is_the_ros2_yaml_launch_format():
    """Only keys that ros2 launch's YAML frontend knows (launch_yaml + launch_ros)."""
    doc = yaml.safe_load(open(SHIPPED))
    allowed = {"arg": {"name", "default", "description"}, "set_env": {"name", "value"},
               "node": {"pkg", "exec", "name", "param", "if", "unless", "namespace", "remap", "ros_args",
                        "args", "launch-prefix", "env"}}
    for entry in doc["launch"]:
        (kind, body), = entry.items()
        assert set(body) <= allowed[kind], (kind, body)
        for p in body.get("param", []) + body.get("env", []):
            assert set(p) == {"name", "value"}


def test_command_line_of_a_node():
    desc = lf.load(SHIPPED, {"model_dir": "/tmp/m x"}, find_share=_share)
    learner = next(n for n in desc.nodes if n.label == "online_learner")
    args = learner.ros_arguments()
    assert args[:3] == ["--ros-args", "-r", "__node:=online_learner"]
    assert "model_dir:='/tmp/m x'" not in args  # a path with a space needs no YAML quotes
    assert "model_dir:=/tmp/m x" in args
    server = desc.nodes[3].ros_arguments()
    assert "model_dir:=''" in server  # the empty string stays a string for rcl's YAML reading


def test_cli_errors_exit_1_with_one_line(tmp_path):
    ciml = os.path.join(sys.prefix, "bin", "ciml")
    for argv in (["launch", str(tmp_path / "missing.yaml")], ["launch", SHIPPED, "nope:=1"],
                 ["launch", SHIPPED, "motion"]):
        r = subprocess.run([ciml, *argv], capture_output=True, text=True, timeout=60)
        assert r.returncode == 1, r
        assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("ciml launch: error:"), r.stderr
    r = subprocess.run([ciml, "launch", "--show-args", SHIPPED], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "online_learning" in r.stdout and "scenario" in r.stdout


@pytest.mark.ros
def test_every_node_reads_the_robot_parameter(tmp_path):
    """Each of the eight nodes, built with robot=go1 in a private context, has go1's joints and
    feet (no node falls back to HyQ); an unknown robot is a one-line CimlError."""
    import importlib
    import random

    import rclpy
    from rclpy.parameter import Parameter

    from ciml_learning.core.errors import CimlError
    from ciml_learning.core.profile import load_profile

    go1 = load_profile("go1").robot()
    classes = {"ciml_sim.bridge_node": "MujocoBridge",
               "ciml_control.nodes.reference_generator": "ReferenceGeneratorNode",
               "ciml_control.nodes.id_controller": "IdControllerNode",
               "ciml_learning.nodes.model_server": "ModelServerNode",
               "ciml_learning.nodes.state_filter": "StateFilterNode",
               "ciml_learning.nodes.error_extractor": "ErrorExtractorNode",
               "ciml_learning.nodes.online_learner": "OnlineLearnerNode",
               "ciml_learning.nodes.state_publisher": "StatePublisherNode"}
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(1, 101))
    try:
        for module, name in classes.items():
            cls = getattr(importlib.import_module(module), name)
            extra = {"OnlineLearnerNode": [Parameter("model_dir", value=str(tmp_path / "m"))],
                     # go1's own layout needs unitree_go's messages; the simulator's graph reads CIML's topics
                     "StateFilterNode": [Parameter("inputs", value="ciml")]}.get(name, [])
            node = cls(context=ctx, parameter_overrides=[Parameter("robot", value="go1"), *extra])
            assert node.robot.joint_names == go1.joint_names and node.robot.foot_frames == go1.foot_frames, name
            node.destroy_node()
            with pytest.raises(CimlError) as err:
                cls(context=ctx, parameter_overrides=[Parameter("robot", value="no_such_robot")])
            assert "no_such_robot" in str(err.value) and "\n" not in str(err.value), name
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_the_learner_pauses_at_info_for_a_missing_reference_and_warns_for_a_fall(tmp_path):
    """online_learner's /diagnostics level follows the pause's reason: a /reference that never came
    (a learner behind on a loaded machine) is OK with the pause text, a fall is WARN."""
    import random

    import rclpy
    from rclpy.parameter import Parameter

    from ciml_learning.learning.learning_gate import FALL, NO_REFERENCE
    from ciml_learning.nodes.online_learner import OnlineLearnerNode
    from ciml_learning.ros.ros_common import OK, WARN

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(1, 101))
    try:
        node = OnlineLearnerNode(context=ctx, parameter_overrides=[Parameter("model_dir", value=str(tmp_path))])
        levels = {}
        for key in (NO_REFERENCE, FALL):
            node.gate.paused, node.gate.key, node.gate.reason = True, key, f"because {key}"
            node._sync_gate()
            levels[key] = (node.health.mode_level, node.health.mode_message)
            node.gate.paused = False
            node._sync_gate()
        assert levels[NO_REFERENCE] == (OK, f"learning paused: because {NO_REFERENCE}"), levels
        assert levels[FALL] == (WARN, f"learning paused: because {FALL}"), levels
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
