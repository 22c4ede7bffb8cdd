"""Long work written to a log file: whole lines, no carriage-return frames, nothing wrapped."""
import io

import pytest
from rich.table import Table

from thermal_comp_common.plain_output import PLAIN_WIDTH, console, progress


def test_progress_off_a_terminal_writes_one_line_per_tenth_and_the_end():
    out = io.StringIO()
    with progress(200, "play", "msg", file=out) as bar:
        for _ in range(200):
            bar.advance()
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert len(lines) == 10, lines
    assert [ln.split(",")[0] for ln in lines] == [f"play: {20 * k}/200 msg ({10 * k} %)" for k in range(1, 11)]
    assert lines[-1].split(", ")[1].startswith("done")


def test_progress_stopped_early_says_so_and_decimals_are_kept():
    out = io.StringIO()
    bar = progress(2.5, "demo", "sim h", file=out, decimals=1)
    bar.to(1.3)
    bar.close()
    bar.close()
    lines = out.getvalue().splitlines()
    assert lines[-1].startswith("demo: 1.3/2.5 sim h (52 %), stopped")
    assert len(lines) == 2     # one line for the jump past 50 %, then the last one


def test_progress_on_a_terminal_is_a_bar():
    out = io.StringIO()
    with progress(10, "x", "row", file=out, terminal=True) as bar:
        bar.to(5)
    assert "\r" in out.getvalue()


@pytest.mark.parametrize("total", [float("nan"), -1, "10"])
def test_progress_refuses_a_bad_total(total):
    with pytest.raises(ValueError, match="progress total"):
        progress(total, "x", "row", file=io.StringIO())


def test_console_off_a_terminal_keeps_long_lines_whole():
    out = io.StringIO()
    c = console(out)
    line = "word " * 60 + "Q_prod about 97 % at the end"
    c.print(line)
    assert out.getvalue() == line + "\n"
    t = Table(title="t")
    for k in range(9):
        t.add_column(f"column number {k}")
    t.add_row(*[f"{k}.000 um" for k in range(9)])
    c.print(t)
    body = out.getvalue().splitlines()[1:]
    assert max(map(len, body)) <= PLAIN_WIDTH and any("column number 8" in ln for ln in body)
