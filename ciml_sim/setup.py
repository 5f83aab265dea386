from glob import glob

from setuptools import find_packages, setup

package_name = "ciml_sim"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/scenarios", glob("config/scenarios/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="CIML developers",
    maintainer_email="ciml@example.com",
    description="MuJoCo HyQ bridge with configurable unmodelled effects; headless recording.",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            "mujoco_bridge = ciml_sim.bridge_node:main",
        ],
        # node classes by executable name, for ciml_container (composition; ciml_learning.ros.container)
        "ciml.nodes": [
            "mujoco_bridge = ciml_sim.bridge_node:MujocoBridge",
        ],
        # `ciml` verbs and benchmarks of this package (ciml_learning.cli.args.Verb; ciml_learning.cli.bench)
        "ciml.verbs": [
            "record = ciml_sim.verbs:RECORD",
            "closed-loop = ciml_sim.verbs:CLOSED_LOOP",
            "gap-bench = ciml_sim.verbs:GAP_BENCH",
            "verify = ciml_sim.verbs:VERIFY",
            "export-mjcf = ciml_sim.verbs:EXPORT_MJCF",
        ],
        "ciml.benchmarks": [
            "sim_headless_speed = ciml_sim.benchmarks:sim_headless_speed",
            "sim_bridge_rate = ciml_sim.benchmarks:rate_benchmark",
            "diagnosis_50k = ciml_sim.benchmarks:diagnosis_benchmark",
            "live_graph_rates = ciml_sim.benchmarks:live_graph_rates",
            "live_online_learning = ciml_sim.benchmarks:live_online_learning",
            "live_graph_memory = ciml_sim.benchmarks:live_graph_memory",
            "scaling = ciml_sim.benchmarks:scaling",
        ],
    },
)
