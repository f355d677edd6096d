"""hsa_mocap_bridge: motion-capture bridge of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_mocap_bridge"

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
        "Motion-capture bridge: PoseStamped of the platform (and base) rigid bodies -> validated "
        "planar end-effector pose in the base frame."
    ),
    license="Apache-2.0",
    entry_points={"console_scripts": ["mocap_bridge = hsa_mocap_bridge.node:main"]},
)
