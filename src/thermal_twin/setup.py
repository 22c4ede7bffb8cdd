"""ament_python package thermal_twin (also installs editable into the repo's venv via setup.sh)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "thermal_twin"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["**/*.yaml", "**/*.csv", "**/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config/presets", sorted(glob(f"{PACKAGE}/presets/*.yaml"))),
    ],
    install_requires=[
        "setuptools", "matplotlib", "numpy", "pyyaml", "rerun-sdk", "scikit-learn", "scipy", "statsmodels",
        "tqdm",
    ],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="Physics simulator (digital twin) of machine cells and the mismatch finder.",
    license="Apache-2.0",
    entry_points={
        # `thermal-comp SUBCOMMAND` looks its subcommands up in this group:
        # "name = module:function" where function(argv: list[str]) -> int.
        "thermal_comp.commands": [
            "calibrate = thermal_twin.calibrate.cli:main",
            "diagnose = thermal_twin.diagnose.cli:main",
            "sim = thermal_twin.sim.cli:main",
            "twin = thermal_twin.identify.cli:main",
        ],
        "console_scripts": [
            "machine_sim = thermal_twin.machine_sim_node:main",
        ],
    },
)
