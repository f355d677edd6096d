"""hsa_live: live view of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_live"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.json")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="hsa-ros developers",
    maintainer_email="hsa-ros@example.org",
    description=(
        "Live view: the running graph (3-D scene, tracking and actuation plots, diagnostics, run "
        "progress) served to Foxglove over WebSocket on 127.0.0.1, with a Foxglove layout."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "live_node = hsa_live.node:main",
        ]
    },
)
