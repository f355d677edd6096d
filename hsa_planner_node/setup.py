"""hsa_planner_node: planner node of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_planner_node"

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
        "Planner node: steady-state setpoint planning service and a setpoint sequencer for step "
        "and contour trajectories."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "planner_node = hsa_planner_node.planner_node:main",
            "setpoint_sequencer = hsa_planner_node.setpoint_sequencer:main",
        ]
    },
)
