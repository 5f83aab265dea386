from glob import glob

from setuptools import find_packages, setup

package_name = "ciml_control"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    # the controller core, built by CMake (cpp/CMakeLists.txt, run by tools/install.sh) before the package is built
    package_data={package_name: ["py.typed", "libciml_control_core.so"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="CIML developers",
    maintainer_email="ciml@example.com",
    description="Inverse-dynamics QP controller with learned model error, gait references.",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            "reference_generator = ciml_control.nodes.reference_generator:main",
            "id_controller = ciml_control.nodes.id_controller:main",
        ],
        # node classes by executable name, for ciml_container (composition; ciml_learning.ros.container)
        "ciml.nodes": [
            "reference_generator = ciml_control.nodes.reference_generator:ReferenceGeneratorNode",
            "id_controller = ciml_control.nodes.id_controller:IdControllerNode",
        ],
        # `ciml bench` benchmarks of this package (ciml_learning.cli.bench)
        "ciml.benchmarks": [
            "id_controller_step = ciml_control.benchmarks:id_controller_step",
            "id_controller_dds_latency = ciml_control.benchmarks:dds_latency_benchmark",
        ],
    },
)
