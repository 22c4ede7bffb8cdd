"""The web viewer, opened in headless Chromium on a short demo recording, shows data in each
of the 7 error plots; and the screenshot reading behind that claim can tell an empty or
squeezed plot from one with data (on drawn pages)."""
import io
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from thermal_comp.view import browser
from thermal_comp.view.screenshot import SEPARATOR, LayoutNotFound, error_plots

N_ERRORS = 7      # the nmv5000 demo's components


def _page(data_cols: slice | None, n_plots: int = N_ERRORS) -> bytes:
    """A drawn page with rerun's layout: top bar and time panel separators, a column divider,
    a 4 x 2 error grid; a magenta line in the first ``n_plots`` cells over ``data_cols``."""
    from PIL import Image
    a = np.full((857, 1600, 3), 255, np.uint8)
    a[35, :] = a[828, :] = SEPARATOR
    a[36:828, 959] = SEPARATOR
    a[205, :959] = a[375, :959] = SEPARATOR
    for x in (239, 479, 719):
        a[36:376, x] = SEPARATOR
    a[100, 20:900] = (120, 120, 120)                     # grey grid line and text: not data
    for k in range(n_plots):
        x0, y0 = 240 * (k % 4), 35 + 170 * (k // 4)
        if data_cols is not None:
            xs = np.arange(x0 + 2, x0 + 237)[data_cols]
            a[y0 + 100, xs] = a[y0 + 101, xs] = (230, 30, 230)
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG")
    return buf.getvalue()


def test_plots_are_found_and_judged_from_the_page():
    full = error_plots(_page(slice(None)), N_ERRORS)
    assert len(full) == 8 and [c.has_data for c in full] == [True] * 7 + [False]   # 8th slot empty
    assert [(c.x0, c.y0) for c in full[:5]] == [(0, 35), (239, 35), (479, 35), (719, 35), (0, 205)]
    assert not any(c.has_data for c in error_plots(_page(None), N_ERRORS))             # empty plots
    squeezed = error_plots(_page(slice(0, 4)), N_ERRORS)                               # data at x = 0
    assert all(c.data_pixels > 0 and not c.has_data for c in squeezed[:7])
    from PIL import Image
    blank = io.BytesIO()
    Image.new("RGB", (1600, 857), "white").save(blank, format="PNG")
    with pytest.raises(LayoutNotFound, match="welcome page"):
        error_plots(blank.getvalue(), N_ERRORS)


def _need_chromium():
    if not browser.CHROMIUM.exists():
        pytest.skip(f"{browser.CHROMIUM} is missing: install Debian's 'chromium' (./setup.sh --with-browser)")


def _check(url, tmp_path, name) -> browser.PlotCheck:
    result = browser.check_error_plots(url, N_ERRORS, timeout_s=300)
    if result.png:
        (tmp_path / f"{name}.png").write_bytes(result.png)
    return result


@pytest.mark.slow
def test_the_demo_recording_shows_every_error_plot_in_chromium(short_demo, tmp_path):
    _need_chromium()
    web, grpc = browser.free_port(), browser.free_port()
    server = browser.serve_rrd(short_demo / "demo.rrd", web, grpc, env=dict(os.environ, HOME=str(tmp_path)))
    try:
        result = _check(browser.viewer_url(web, grpc), tmp_path, "demo_rrd")
    finally:
        browser.stop_server(server)
    assert result.with_data == N_ERRORS and result.settled, (result.note, tmp_path)


@pytest.mark.slow
def test_view_serve_web_of_the_demo_bag_shows_every_error_plot(short_demo, tmp_path):
    _need_chromium()
    web, grpc = browser.free_port(), browser.free_port()
    viewer = subprocess.Popen([sys.executable, "-m", "thermal_comp.view.cli", str(short_demo / "bag"),
                               "--serve-web", "--web-port", str(web), "--grpc-port", str(grpc), "--no-progress"],
                              env=dict(os.environ, HOME=str(tmp_path)), stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    try:
        line = viewer.stdout.readline()
        assert line.startswith("rerun web viewer: http://localhost:"), line
        assert "messages logged" in viewer.stdout.readline()
        result = _check(line.split(": ", 1)[1].strip(), tmp_path, "view_serve_web")
    finally:
        viewer.terminate()
        viewer.communicate(timeout=30)
    assert result.with_data == N_ERRORS and result.settled, (result.note, tmp_path)
