"""ament_python package thermal_comp_testing (also installs editable into the repo's venv via setup.sh)."""
from setuptools import find_packages, setup

PACKAGE = "thermal_comp_testing"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools", "pytest"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="Test support: the pytest plugin (isolated ROS 2 environment per test process, markers, fixtures) of every package's tests.",
    license="Apache-2.0",
    entry_points={
        # pytest loads every installed pytest11 entry point; `-p no:thermal_comp_testing` turns it off.
        "pytest11": ["thermal_comp_testing = thermal_comp_testing.pytest_plugin"],
    },
)
