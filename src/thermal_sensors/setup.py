"""ament_python package thermal_sensors (also installs editable into the repo's venv via setup.sh)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "thermal_sensors"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["**/*.yaml", "**/*.csv", "**/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", sorted(glob(f"{PACKAGE}/config/*.yaml"))),
    ],
    install_requires=["setuptools", "numpy", "pymodbus", "pyyaml", "tqdm"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="Temperature publishers: twin, CSV replay and Modbus RTD modules.",
    license="Apache-2.0",
    entry_points={
        # `thermal-comp SUBCOMMAND` looks its subcommands up in this group:
        # "name = module:function" where function(argv: list[str]) -> int.
        "thermal_comp.commands": [
            "rtd-emulator = thermal_sensors.rtd_emulator_cli:main",
        ],
        "console_scripts": [
            "temperature_publisher = thermal_sensors.temperature_publisher_node:main",
        ],
    },
)
