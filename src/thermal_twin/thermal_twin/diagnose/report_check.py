"""Does ``report.md`` claim more than ``report.json``? Two checks, both pure text + dict.

:func:`underived_numbers`: every number printed in the markdown must be a number of the JSON
(a value, or a number inside one of its strings such as a formula), a time in seconds printed
in hours (/3600) or a share printed in percent (x100), within the rounding of the printed digits.
Digits inside names (``T11_c``, ``E_X0C``) are not numbers; the labels in :data:`LABELS` are
the template's own (a 95 % interval is a label, not a result), and so is a table row's rank.

:func:`contradicted_claims`: a line that claims a held-out improvement for a channel (an
``unnamed`` term ``C += ...``) while the report's own channel table shows that channel's held-out
RMSE rising, or an adopted effect claimed to improve the held-out fit while the table's
noise-weighted held-out sum over all channels rises.
"""
from __future__ import annotations

import math
import re

LABELS = {95.0}                  # "95 % interval", "95 % band": the template's labels
CLAIM = re.compile(r"held-out improvement ([-+]?\d+(?:\.\d+)?) %")
UNNAMED = re.compile(r"`(\S+) \+= ")


def json_numbers(x, out: list[float] | None = None) -> list[float]:
    """Every number in a JSON value, those written inside its strings included."""
    out = [] if out is None else out
    if isinstance(x, bool) or x is None:
        return out
    if isinstance(x, (int, float)):
        if math.isfinite(float(x)):
            out.append(float(x))
    elif isinstance(x, str):
        out += [float(m) for m in re.findall(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", x)]
    elif isinstance(x, dict):
        for v in x.values():
            json_numbers(v, out)
    elif isinstance(x, (list, tuple)):
        for v in x:
            json_numbers(v, out)
    return out


def _tolerance(text: str) -> float:
    mant, _, exp = text.lower().partition("e")
    decimals = len(mant.split(".")[1]) if "." in mant else 0
    return 0.5 * 10.0 ** (int(exp or 0) - decimals) * 1.0001 + 1e-12


def _numbers(line: str) -> list[str]:
    """Numbers of a markdown line that are not part of a name (``T11_c``, ``ch5_um``)."""
    out = []
    for m in re.finditer(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", line):
        before = line[m.start() - 1] if m.start() > 0 else " "
        after = line[m.end()] if m.end() < len(line) else " "
        if before.isalnum() or before in "_." or after.isalpha() or after == "_":
            continue
        out.append(m.group())
    return out


def underived_numbers(md: str, report: dict) -> list[str]:
    """Numbers printed in ``md`` that no number of ``report`` gives; [] when all derive."""
    values = json_numbers(report)
    cands = sorted({v for x in values for v in (x, abs(x), x / 3600.0, abs(x) / 3600.0, 100.0 * x, 100.0 * abs(x))})
    bad = []
    for line in md.splitlines():
        # a table row's first cell "| 17 |" is its rank (the row's position), a label
        line = re.sub(r"^\|\s*\d+\s*\|", "| |", line)
        for text in _numbers(line):
            x, tol = float(text), _tolerance(text)
            if abs(x) in LABELS:
                continue
            lo = _bisect(cands, x - tol)
            if not (lo < len(cands) and cands[lo] <= x + tol):
                bad.append(f"{text} in: {line.strip()[:120]}")
    return bad


def _bisect(a: list[float], x: float) -> int:
    lo, hi = 0, len(a)
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _weighted_holdout(channels: dict, key: str) -> float:
    return sum((d[key] / d["noise_sigma"]) ** 2 for d in channels.values()
               if d.get(key) is not None and d.get("noise_sigma"))


def contradicted_claims(md: str, report: dict) -> list[str]:
    """Lines of ``md`` claiming a held-out improvement the report's channel table contradicts."""
    chans = report.get("channels", {})
    total_worse = _weighted_holdout(chans, "holdout_rmse_after") > _weighted_holdout(chans, "holdout_rmse_before")
    bad = []
    for line in md.splitlines():
        claim = CLAIM.search(line)
        if not claim or float(claim.group(1)) <= 0:
            continue
        u = UNNAMED.search(line)
        if u and u.group(1) in chans:
            d = chans[u.group(1)]
            if d["holdout_rmse_after"] > d["holdout_rmse_before"]:
                bad.append(f"{line.strip()[:100]}: the channel table shows {u.group(1)} held-out "
                           f"{d['holdout_rmse_before']:.3g} -> {d['holdout_rmse_after']:.3g}")
        elif line.lstrip().startswith("- **") and total_worse:
            bad.append(f"{line.strip()[:100]}: the channel table's weighted held-out sum rises")
    return bad


def check_report(md: str, report: dict) -> list[str]:
    """Every problem of ``md`` against ``report`` (underived numbers, contradicted claims)."""
    return [f"not in report.json: {b}" for b in underived_numbers(md, report)] + \
           [f"contradicted: {b}" for b in contradicted_claims(md, report)]
