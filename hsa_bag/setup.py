"""hsa_bag: MCAP record/replay and offline analysis of hsa-ros runs (ament_python)."""

from setuptools import find_packages, setup

PACKAGE = "hsa_bag"

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
    description="MCAP record and replay of hsa-ros topics and offline analysis of recorded runs.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "bag_recorder = hsa_bag.recorder:main",
            "bag_player = hsa_bag.player:main",
            "bag_recover = hsa_bag.recover:main",
            "hsa_analyze = hsa_bag.analysis:main",
        ]
    },
)
