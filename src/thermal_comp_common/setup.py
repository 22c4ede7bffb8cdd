"""ament_python package thermal_comp_common (also installs editable into the repo's venv via setup.sh)."""
from setuptools import find_packages, setup

PACKAGE = "thermal_comp_common"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["**/*.yaml", "**/*.csv", "**/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=[
        "setuptools", "dask", "distributed", "mcap", "numpy", "pyyaml", "rich", "rosbags",
        "threadpoolctl", "tqdm",
    ],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="Ground floor of the thermal-comp graph: node runtime, topic names, QoS, message and bag helpers, the recording format.",
    license="Apache-2.0",
)
