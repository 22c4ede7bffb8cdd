"""ament_python package probe_cycle (also installs editable into the repo's venv via setup.sh)."""
from setuptools import find_packages, setup

PACKAGE = "probe_cycle"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["**/*.yaml", "**/*.csv", "**/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools", "asyncua", "numpy", "scipy"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="ProbeCycle action server: sphere cycle of a 5-axis machine, guide-bush probing of a Swiss-type lathe.",
    license="Apache-2.0",
    entry_points={
        # `thermal-comp SUBCOMMAND` looks its subcommands up in this group:
        # "name = module:function" where function(argv: list[str]) -> int.
        "thermal_comp.commands": [
        ],
        "console_scripts": [
            "probe_cycle_server = probe_cycle.probe_cycle_node:main",
        ],
    },
)
