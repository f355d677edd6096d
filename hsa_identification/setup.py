"""hsa_identification: calibration and system-identification tools of hsa-ros (ament_python)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "hsa_identification"

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
        "Excitation (steps, staircases, GBN), rest-strain calibration, least-squares "
        "identification, model verification and the workspace map."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "excitation_player = hsa_identification.excitation_player:main",
            "calibration_node = hsa_identification.calibration_node:main",
            "hsa_identify = hsa_identification.cli:identify_main",
            "hsa_verify = hsa_identification.cli:verify_main",
            "hsa_workspace = hsa_identification.cli:workspace_main",
        ]
    },
)
