"""ROS-free core library of hsa-ros (also buildable by colcon as an ament_python package)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_core"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={
        PACKAGE: [
            "config/*.yaml",
            "config/robots/*.yaml",
            "config/gains/*.yaml",
            "config/realdata/*.csv",
            "config/realdata/*.yaml",
            "config/realdata/*.md",
            "config/world/*.yaml",
        ]
    },
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("hsa_core/config/*.yaml")),
        (f"share/{PACKAGE}/config/robots", glob("hsa_core/config/robots/*.yaml")),
        (f"share/{PACKAGE}/config/gains", glob("hsa_core/config/gains/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="hsa-ros developers",
    maintainer_email="hsa-ros@example.org",
    description=(
        "Model, planning, control, estimation and simulation of planar HSA robots (no ROS imports)."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "hsa_experiment = hsa_core.sim.experiment:main",
            "hsa_robustness = hsa_core.apps.robustness:main",
            "hsa_tune = hsa_core.apps.tune:main",
            "hsa_calibrate = hsa_core.apps.calibrate:main",
        ]
    },
)
