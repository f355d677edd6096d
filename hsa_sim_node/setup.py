"""hsa_sim_node: simulator node replacing the hardware of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_sim_node"

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
        "Simulator node replacing the hardware: emulated MX-28 bus on a pseudo-terminal and mocap "
        "poses from the JAX model."
    ),
    license="Apache-2.0",
    entry_points={"console_scripts": ["sim_node = hsa_sim_node.node:main"]},
)
