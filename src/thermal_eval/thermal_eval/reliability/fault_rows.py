"""Rows of ``thermal-comp bench faults`` that cannot take the table down: :func:`guarded` runs
one row (or a group of rows) and turns an exception into one failed row with its reason, so
the other rows are kept."""
from __future__ import annotations

from typing import Callable


def failed_row(area: str, fault: str, exc: BaseException) -> dict:
    """The row of a case that could not run: not survived, its reason in the detail."""
    reason = f"{type(exc).__name__}: {exc}".strip().rstrip(":")
    return {"area": area, "fault": fault, "injected": 0, "survived": False, "data_lost": 0,
            "unsafe_writes": 0, "detail": f"did not run: {reason}"[:90], "why": reason}


def guarded(area: str, fault: str, make: Callable[[], dict | list[dict]]) -> list[dict]:
    """``make()``'s row(s) as a list, or one :func:`failed_row` if it raises."""
    try:
        got = make()
    except Exception as exc:  # noqa: BLE001 - any failure of a case is that case's row, not the table's
        return [failed_row(area, fault, exc)]
    return got if isinstance(got, list) else [got]
