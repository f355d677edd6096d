"""hsa_controller_node: controller node of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_controller_node"

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
        "Controller node: P-satI-D, P-satI-D + gravity cancellation and the task-space PID "
        "baseline at a fixed rate."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": ["controller_node = hsa_controller_node.controller_node:main"]
    },
)
