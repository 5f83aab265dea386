from glob import glob

from setuptools import find_packages, setup

package_name = "ciml_learning"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["py.typed", "libciml_learning_core.so"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/layouts", glob("config/layouts/*")),  # Foxglove, PlotJuggler
        ("share/" + package_name + "/config/robots", glob("config/robots/*.yaml")),  # robot profiles
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="CIML developers",
    maintainer_email="ciml@example.com",
    description="Contact-invariant model learning: robot model, filtering, error extraction, learners, diagnosis, CLI.",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            "ciml = ciml_learning.cli.main:main",
            "state_filter = ciml_learning.nodes.state_filter:main",
            "error_extractor = ciml_learning.nodes.error_extractor:main",
            "online_learner = ciml_learning.nodes.online_learner:main",
            "model_server = ciml_learning.nodes.model_server:main",
            "state_publisher = ciml_learning.nodes.state_publisher:main",
            "ciml_container = ciml_learning.ros.container:main",
        ],
        # node classes by executable name, for ciml_container (composition; ciml_learning.ros.container)
        "ciml.nodes": [
            "state_filter = ciml_learning.nodes.state_filter:StateFilterNode",
            "error_extractor = ciml_learning.nodes.error_extractor:ErrorExtractorNode",
            "online_learner = ciml_learning.nodes.online_learner:OnlineLearnerNode",
            "model_server = ciml_learning.nodes.model_server:ModelServerNode",
            "state_publisher = ciml_learning.nodes.state_publisher:StatePublisherNode",
        ],
        # `ciml` verbs and benchmarks of this package (ciml_learning.cli.args.Verb; ciml_learning.cli.bench)
        "ciml.verbs": [
            "extract = ciml_learning.cli.verbs:EXTRACT",
            "train = ciml_learning.cli.verbs:TRAIN",
            "evaluate = ciml_learning.cli.verbs:EVALUATE",
            "diagnose = ciml_learning.cli.verbs:DIAGNOSE",
            "play = ciml_learning.cli.verbs:PLAY",
            "bench = ciml_learning.cli.verbs:BENCH",
            "launch = ciml_learning.cli.verbs:LAUNCH",
            "inspect = ciml_learning.cli.verbs:INSPECT",
        ],
        "ciml.benchmarks": [
            "extraction_throughput = ciml_learning.cli.benchmarks:extraction_throughput",
            "lwpr_cross_2d = ciml_learning.cli.benchmarks:lwpr_cross_2d",
            "lwpr_online_30dims = ciml_learning.cli.benchmarks:lwpr_online_30dims",
            "train_lwpr_paper_size = ciml_learning.cli.benchmarks:train_lwpr_paper_size",
            "train_sgpr_paper_size = ciml_learning.cli.benchmarks:train_sgpr_paper_size",
            "online_nodes_per_sample = ciml_learning.cli.benchmarks:online_nodes_per_sample",
            "extraction_batching = ciml_learning.cli.benchmarks:extraction_batching",
        ],
    },
)
