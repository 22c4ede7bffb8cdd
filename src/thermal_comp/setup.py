"""ament_python package thermal_comp (also installs editable into the repo's venv via setup.sh)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "thermal_comp"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["**/*.yaml", "**/*.csv", "**/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
        # the example cell files live at the repository top (config/cells/)
        (f"share/{PACKAGE}/config/cells", sorted(glob("../../config/cells/*.yaml"))),
    ],
    install_requires=[
        "setuptools", "matplotlib", "numpy", "psutil", "pyyaml", "rerun-sdk", "rich",
        "pillow", "websocket-client",   # the headless-browser check of the web viewer (view.browser)
    ],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="The thermal-comp command: launcher, inspection, record/replay, rerun view, demo and benchmarks.",
    license="Apache-2.0",
    entry_points={
        # `thermal-comp SUBCOMMAND` looks its subcommands up in this group:
        # "name = module:function" where function(argv: list[str]) -> int.
        "thermal_comp.commands": [
            "launch = thermal_comp.cell.launcher:main",
            "topics = thermal_comp.cell.inspect_cli:topics_main",
            "echo = thermal_comp.cell.inspect_cli:echo_main",
            "nodes = thermal_comp.cell.inspect_cli:nodes_main",
            "probe = thermal_comp.cell.inspect_cli:probe_main",
            "frames = thermal_comp.frames.cli:main",
            "demo = thermal_comp.demo.cli:main",
            "record = thermal_comp.bags.record_cli:main",
            "play = thermal_comp.bags.play_cli:main",
            "import-csv = thermal_comp.bags.import_csv_cli:main",
            "view = thermal_comp.view.cli:main",
            "prior = thermal_comp.prior.cli:main",
        ],
        # `thermal-comp bench SUITE`: "suite = module:function" where function(args) -> dict of figures.
        "thermal_comp.bench": [
            "graph = thermal_comp.demo.graph:bench_graph",
        ],
        "console_scripts": [
            "thermal-comp = thermal_comp.cli:main",
            "bag_recorder = thermal_comp.bags.recorder_node:main",
            "bag_player = thermal_comp.bags.player_node:main",
            "rerun_view = thermal_comp.view.rerun_view_node:main",
            "static_frames = thermal_comp.frames.static_frames_node:main",
        ],
    },
)
