"""hsa_dynamixel_driver: dynamixel driver of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_dynamixel_driver"

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
        "Dynamixel driver: 4 MX-28 servos over Protocol 2.0 with one sync read and one sync write "
        "per cycle, limits and torque safety."
    ),
    license="Apache-2.0",
    entry_points={"console_scripts": ["dynamixel_driver = hsa_dynamixel_driver.node:main"]},
)
