"""ament_python package cnc_bridge (also installs editable into the repo's venv via setup.sh)."""
from setuptools import find_packages, setup

PACKAGE = "cnc_bridge"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["**/*.yaml", "**/*.csv", "**/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools", "asyncua", "cryptography", "numpy", "pyyaml"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="Predicted thermal errors to bounded, rate-limited CNC axis offsets over OPC UA.",
    license="Apache-2.0",
    entry_points={
        # `thermal-comp SUBCOMMAND` looks its subcommands up in this group:
        # "name = module:function" where function(argv: list[str]) -> int.
        "thermal_comp.commands": [
            "cnc-emulator = cnc_bridge.cnc_emulator.cli:main",
        ],
        "console_scripts": [
            "cnc_bridge = cnc_bridge.cnc_bridge_node:main",
        ],
    },
)
