"""The thermal-comp command: launcher of cells, inspection, record/replay, rerun view and the
demo (a compensated cell end to end on the twin). Cells and the demo need ROS 2 at run time."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "cell.config": ["CellConfig", "CellConfigError", "load_cell", "parse_cell"],
    "cell.launcher": ["Launcher"],
    "demo.cell": ["DemoConfig", "DemoError", "build_cell"],
    "demo.graph": ["RunRecord", "run_graph"],
    "demo.series": ["DemoSeries", "read_series"],
    "demo.summary": ["compensation_in_effect", "summarise"],
    "demo.run": ["run_demo"],
})
