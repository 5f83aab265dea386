from glob import glob

from setuptools import find_packages, setup

package_name = "ciml_learning"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["py.typed"]},
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
            "ciml = ciml_learning.cli:main",
            "state_filter = ciml_learning.nodes.state_filter:main",
            "error_extractor = ciml_learning.nodes.error_extractor:main",
            "online_learner = ciml_learning.nodes.online_learner:main",
            "model_server = ciml_learning.nodes.model_server:main",
            "state_publisher = ciml_learning.nodes.state_publisher:main",
            "ciml_container = ciml_learning.container:main",
        ],
        # node classes by executable name, for ciml_container (composition; ciml_learning.container)
        "ciml.nodes": [
            "state_filter = ciml_learning.nodes.state_filter:StateFilterNode",
            "error_extractor = ciml_learning.nodes.error_extractor:ErrorExtractorNode",
            "online_learner = ciml_learning.nodes.online_learner:OnlineLearnerNode",
            "model_server = ciml_learning.nodes.model_server:ModelServerNode",
            "state_publisher = ciml_learning.nodes.state_publisher:StatePublisherNode",
        ],
        # `ciml` verbs and benchmarks of this package (ciml_learning.cliargs.Verb; ciml_learning.bench)
        "ciml.verbs": [
            "extract = ciml_learning.verbs:EXTRACT",
            "train = ciml_learning.verbs:TRAIN",
            "evaluate = ciml_learning.verbs:EVALUATE",
            "diagnose = ciml_learning.verbs:DIAGNOSE",
            "play = ciml_learning.verbs:PLAY",
            "bench = ciml_learning.verbs:BENCH",
            "launch = ciml_learning.verbs:LAUNCH",
            "inspect = ciml_learning.verbs:INSPECT",
        ],
        "ciml.benchmarks": [
            "extraction_throughput = ciml_learning.benchmarks:extraction_throughput",
            "lwpr_cross_2d = ciml_learning.benchmarks:lwpr_cross_2d",
            "lwpr_online_30dims = ciml_learning.benchmarks:lwpr_online_30dims",
            "train_lwpr_paper_size = ciml_learning.benchmarks:train_lwpr_paper_size",
            "train_sgpr_paper_size = ciml_learning.benchmarks:train_sgpr_paper_size",
            "online_nodes_per_sample = ciml_learning.benchmarks:online_nodes_per_sample",
            "extraction_batching = ciml_learning.benchmarks:extraction_batching",
        ],
    },
)
