"""ament_python package thermal_eval (also installs editable into the repo's venv via setup.sh)."""
from setuptools import find_packages, setup

PACKAGE = "thermal_eval"

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
        "setuptools", "asyncua", "distributed", "matplotlib", "numpy", "psutil", "pyyaml", "rerun-sdk", "rich",
        "rosbags", "scikit-learn", "scipy", "statsmodels", "sysidentpy", "tqdm",
    ],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest when a package asks for it
    zip_safe=False,
    maintainer="thermal-comp developers",
    maintainer_email="thermal-comp@example.org",
    description="Evaluation of thermal-comp: benchmarks, dataset loaders, replay, sweeps, virtual experiments, fault injection.",
    license="Apache-2.0",
    entry_points={
        # `thermal-comp SUBCOMMAND` looks its subcommands up in this group:
        # "name = module:function" where function(argv: list[str]) -> int.
        "thermal_comp.commands": [
            "bench = thermal_eval.bench.cli:main",
            "evaluate = thermal_eval.evaluate.cli:main",
            "learn = thermal_eval.learn.cli:main",
            "replay = thermal_eval.replay.cli:main",
            "sweep = thermal_eval.sweep.cli:main",
        ],
        # `thermal-comp bench SUITE`: "suite = module:function" where function(args) -> dict of figures.
        "thermal_comp.bench": [
            "bags = thermal_eval.bench.bags:run",
            "bridge = thermal_eval.bench.bridge:run",
            "cli = thermal_eval.bench.cli_start:run",
            "diagnose = thermal_eval.bench.diagnose:run",
            "evaluate = thermal_eval.bench.evaluate:run",
            "faults = thermal_eval.bench.faults:run",
            "fl-thermal = thermal_eval.fl_thermal.benchmark:run",
            "learn = thermal_eval.learn.bench:run",
            "model = thermal_eval.bench.model:run",
            "models = thermal_eval.bench.sweep:run",
            "probe = thermal_eval.bench.probe:run",
            "scale = thermal_eval.bench.scale:run",
            "sensors = thermal_eval.bench.sensors:run",
            "twin = thermal_eval.bench.twin:run",
            "twin-init = thermal_eval.twin_init.bench:run",
            "view = thermal_eval.bench.view:run",
            "hold-fallback = thermal_eval.model_bench.hold_fallback:run",
            "history-prior = thermal_eval.model_bench.history_prior:run",
        ],
        # twin scenarios a dataset owns: "name = module:SCENARIO" (thermal_twin.sim.scenarios.PLUGIN_GROUP)
        "thermal_twin.sim.scenarios": ["fl-thermal-programme = thermal_eval.fl_thermal.scenario:SCENARIO"],
    },
)
