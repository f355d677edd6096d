"""hsa_kinematics_node: kinematics node of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_kinematics_node"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="hsa-ros developers",
    maintainer_email="hsa-ros@example.org",
    description=(
        "Kinematics node: closed-form inverse kinematics and Savitzky-Golay velocity estimation "
        "per mocap sample; marker node: RViz/Foxglove markers of the robot and the setpoint."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "kinematics_node = hsa_kinematics_node.node:main",
            "marker_node = hsa_kinematics_node.marker_node:main",
        ]
    },
)
