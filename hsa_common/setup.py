"""hsa_common: ROS 2 glue shared by the hsa-ros nodes, and the venv launcher (ament_python)."""

from setuptools import find_packages, setup

PACKAGE = "hsa_common"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="hsa-ros developers",
    maintainer_email="hsa-ros@example.org",
    description=(
        "ROS 2 glue shared by the hsa-ros nodes, and the venv launcher for "
        "launch_scripts/*.launch.yaml."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "hsa_launch = hsa_common.launcher:main",
            "hsa_compose = hsa_common.compose:main",
        ]
    },
)
