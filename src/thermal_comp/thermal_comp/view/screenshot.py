"""What a screenshot of rerun's viewer shows: where the error plots of the default blueprint
are, and whether each holds data.

The plots are located from the page itself, not from the data: rerun draws a one-pixel
separator line (``SEPARATOR`` grey) between views. The viewport lies between the first and
the last full-width separator (top bar, time panel); the main column divider is the longest
vertical separator; the error grid is the region its internal vertical separators span
(top left, see ``blueprint.default_blueprint``), cut into cells by them and by the horizontal
separators across it. Cells are numbered in reading order, as rerun fills a grid. A cell shows
data when its plot area (below the view's title bar) holds enough strongly coloured pixels
(axes, grid lines, text and icons are grey; our series are magenta, blue and orange) spread
over at least half of its width: data squeezed into a sliver at one end (a timeline running
far past the data) does not count.
"""
from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

SEPARATOR = (223, 223, 223)
#: title bar of a view, px below its top separator (skipped: it holds only grey text and icons)
TITLE_BAR_PX = 26
#: a pixel is "data" when max - min of its RGB reaches this (grey has 0)
MIN_CHROMA = 80
#: a plot "shows data" with at least this many data pixels (a line across a tile has hundreds)
MIN_DATA_PIXELS = 50
#: ... in at least this share of its pixel columns
MIN_WIDTH_SHARE = 0.5


class LayoutNotFound(ValueError):
    """The screenshot does not show the blueprint's error grid; the message says what is missing."""


@dataclass
class Cell:
    x0: int
    y0: int
    x1: int
    y1: int
    data_pixels: int = 0
    width_share: float = 0.0       # share of the plot area's pixel columns holding data

    @property
    def has_data(self) -> bool:
        return self.data_pixels >= MIN_DATA_PIXELS and self.width_share >= MIN_WIDTH_SHARE


def load_rgb(png: bytes) -> np.ndarray:
    from PIL import Image  # Pillow comes with matplotlib; only needed for screenshots
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def _first_run(line: np.ndarray) -> int:
    """Length of the run of True at the start of a 1-D boolean array (allowing 3 px of gap at
    the very start and single-pixel gaps, where separators cross)."""
    line = line.copy()
    line[1:-1] |= line[:-2] & line[2:]
    start = next((i for i in range(min(4, len(line))) if line[i]), None)
    if start is None:
        return 0
    stop = np.flatnonzero(~line[start:])
    return int(stop[0]) if len(stop) else len(line) - start


def _lines(counts: np.ndarray, min_len: int) -> list[int]:
    """Indices whose count reaches ``min_len``, adjacent ones merged (their first)."""
    idx = [int(i) for i in np.flatnonzero(counts >= min_len)]
    return [i for k, i in enumerate(idx) if k == 0 or idx[k - 1] != i - 1]


def error_grid_cells(rgb: np.ndarray) -> list[Cell]:
    """The cells of the error grid, in reading order (see the module doc)."""
    h, w, _ = rgb.shape
    sep = np.abs(rgb - np.array(SEPARATOR)).sum(axis=-1) <= 3
    full_rows = _lines(sep.sum(axis=1), int(0.95 * w))
    if len(full_rows) < 2:
        raise LayoutNotFound("no top bar and time panel separators: not rerun's viewer (welcome page?)")
    top, bottom = full_rows[0], full_rows[-1]
    body = sep[top + 1:bottom]
    divider = int(np.argmax(body.sum(axis=0)))
    if body[:, divider].sum() < 0.8 * body.shape[0]:
        raise LayoutNotFound("no column divider: the blueprint's layout is not shown")
    runs = np.array([_first_run(body[:, x]) for x in range(divider)])    # from the top bar down
    inner = _lines(runs, 60)
    if not inner:
        raise LayoutNotFound("no grid of error plots (one column at most)")
    grid_bottom = top + 1 + max(int(runs[x]) for x in inner)
    rows = [y for y in _lines(sep[top + 1:grid_bottom, :divider].sum(axis=1), int(0.9 * divider))
            if y < grid_bottom - top - 3]      # not the separator under the grid
    ys = [top] + [top + 1 + y for y in rows] + [grid_bottom]
    xs = [0] + inner + [divider]
    return [Cell(xs[i], ys[j], xs[i + 1], ys[j + 1]) for j in range(len(ys) - 1) for i in range(len(xs) - 1)]


def measure(rgb: np.ndarray, cell: Cell) -> None:
    """Set the cell's data pixels and the share of its columns holding any."""
    area = rgb[cell.y0 + TITLE_BAR_PX:cell.y1 - 1, cell.x0 + 1:cell.x1 - 1]
    data = (area.max(axis=-1) - area.min(axis=-1)) >= MIN_CHROMA
    cell.data_pixels = int(data.sum())
    cell.width_share = round(float(data.any(axis=0).mean()), 3) if data.size else 0.0


def error_plots(png: bytes, n_plots: int) -> list[Cell]:
    """The first ``n_plots`` cells of the error grid with their data pixel counts; LayoutNotFound
    when the page does not show that many."""
    rgb = load_rgb(png)
    cells = error_grid_cells(rgb)
    if len(cells) < n_plots:
        raise LayoutNotFound(f"{len(cells)} cells in the error grid, expected {n_plots} plots")
    for c in cells:
        measure(rgb, c)
    return cells
