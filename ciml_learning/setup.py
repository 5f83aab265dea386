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
        ],
    },
)
