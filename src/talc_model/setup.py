"""ament_python package talc_model (also installs editable into the repo's venv via setup.sh)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "talc_model"

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
    install_requires=["setuptools", "numpy", "pyyaml", "scikit-learn", "scipy"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="Adaptive thermal-error models: TALC (ARX), adaptive Gaussian process, characteristic diagrams.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "talc_model = talc_model.talc_model_node:main",
            "learner = talc_model.learner_node:main",
        ],
    },
)
