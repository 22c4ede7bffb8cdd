"""The view's default rerun blueprint: the layout every recording we write opens with, on
simulated time with the whole recording in each plot."""
from __future__ import annotations

from typing import Iterable

import rerun.blueprint as rrb

from thermal_comp.view.rerun_logging import TIMELINE, path_part


def _series(origin: str, name: str, **kw) -> rrb.TimeSeriesView:
    """A time-series view whose x axis shows the whole recording (not only the last seconds)."""
    whole = rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
    return rrb.TimeSeriesView(origin=origin, name=name, axis_x=rrb.TimeAxis(view_range=whole), **kw)


def default_blueprint(namespace: str = "", error_components: Iterable[str] = ()) -> rrb.Blueprint:
    """Errors (one plot per component when they are known: units differ), temperatures,
    offsets and model on the left; 3D sensor layout, machine state and, in tabs, events,
    health (``/diagnostics``, the tab shown) and the ``/rosout`` log on the right."""
    p = f"/{namespace.strip('/')}" if namespace.strip("/") else ""
    comps = list(error_components)
    if comps:
        # small tiles: no legend (it would hide the curves); colours as in COLOURS and the title
        errors = rrb.Grid(*[_series(f"{p}/errors/{path_part(c)}",
                                    f"{c}: true magenta, predicted +-2u blue, measured orange",
                                    plot_legend=rrb.PlotLegend(visible=False))
                            for c in comps])
    else:
        errors = _series(f"{p}/errors", "Thermal errors (true / predicted +-2u / measured)")
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                errors,
                _series(f"{p}/temperatures", "Temperatures (degC)"),
                rrb.Horizontal(
                    _series(f"{p}/offsets", "CNC offsets (um)"),
                    _series(f"{p}/model", "Model"),
                ),
                row_shares=[3, 2, 2] if comps else [2, 2, 2],
            ),
            rrb.Vertical(
                rrb.Spatial3DView(origin=f"{p}/machine/sensors", name="Sensor layout"),
                _series(f"{p}/machine", "Machine state", contents=["$origin/**", "- $origin/sensors/**"]),
                # health in front: the bridge's status (what it writes to the CNC) at a glance
                rrb.Tabs(rrb.TextLogView(origin=f"{p}/events", name="Events"),
                         rrb.TextLogView(origin="/diagnostics", name="Health (/diagnostics)"),
                         rrb.TextLogView(origin="/rosout", name="Log (/rosout)"), active_tab=1),
            ),
            column_shares=[3, 2],
        ),
        # opens on simulated time, the cursor on the newest data (each plot shows the whole run)
        rrb.TimePanel(timeline=TIMELINE, state="collapsed", play_state="following"),
        collapse_panels=True,
    )
