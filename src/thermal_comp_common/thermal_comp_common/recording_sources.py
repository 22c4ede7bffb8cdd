"""Which recordings make a data set: files, folders, globs or a manifest with per-run metadata.

A source is a recording file (CSV, ``.mcap`` or a bag folder), a folder of recordings (every
``*.csv`` / ``*.mcap`` in it, sorted), a glob (``runs/2026-*.csv``) or a manifest: a YAML file
(``runs:`` a list of mappings, or the list itself) or a CSV whose header has a ``path``
column. A manifest row names ``path`` (relative to the manifest) and optionally ``name``,
``unit``, ``programme``, ``date`` (ISO, YYYY-MM-DD) and ``hall_setpoint_c``. Every bad entry is
one :class:`DatasetError` naming the file, the field and the value. Pure: no model, no rclpy.
It lives below thermal_eval and thermal_twin so that evaluate, replay and calibrate take the
same sources.
"""
from __future__ import annotations

import csv
import datetime
import glob
import io
import math
import pathlib
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import yaml

#: metadata a manifest row may carry beside ``path``
META_FIELDS = ("name", "unit", "programme", "date", "hall_setpoint_c")
RECORDING_SUFFIXES = (".csv", ".mcap")


class _TextDates(yaml.SafeLoader):
    """YAML without implicit timestamps: a date stays text, so a bad one is named as a field."""


_TextDates.yaml_implicit_resolvers = {
    k: [(tag, rx) for tag, rx in v if tag != "tag:yaml.org,2002:timestamp"]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}


class DatasetError(ValueError):
    """A bad source, manifest entry or split of runs; the message names file, field and value."""


@dataclass(frozen=True)
class RunEntry:
    """One run of the data set: where it is and what is known about it."""

    path: str
    name: str
    unit: str = ""
    programme: str = ""
    date: str = ""
    hall_setpoint_c: float | None = None
    extra: dict[str, str] = field(default_factory=dict, compare=False)

    def meta(self, key: str) -> str:
        """The value of a metadata field as text ('' when unknown), for grouping."""
        if key == "name":
            return self.name
        v = getattr(self, key, None) if key in META_FIELDS else self.extra.get(key)
        return "" if v is None else (f"{v:g}" if isinstance(v, float) else str(v))


def _is_bag_folder(p: pathlib.Path) -> bool:
    return p.is_dir() and (p / "metadata.yaml").is_file()


def is_manifest(p: pathlib.Path) -> bool:
    if p.suffix.lower() in (".yaml", ".yml"):
        return True
    if p.suffix.lower() != ".csv" or not p.is_file():
        return False
    with p.open(encoding="utf-8-sig", errors="replace") as f:
        header = next(csv.reader([f.readline()]), [])
    return "path" in [h.strip() for h in header]


def _entry(row: Mapping[str, Any], where: str, base: pathlib.Path) -> RunEntry:
    path = str(row.get("path") or "").strip()
    if not path:
        raise DatasetError(f"{where}: field 'path' is missing or empty")
    full = pathlib.Path(path) if pathlib.Path(path).is_absolute() else base / path
    if not full.exists():
        raise DatasetError(f"{where}: field 'path' = {path!r}: no such file ({full})")
    meta: dict[str, Any] = {}
    for k in ("unit", "programme", "name"):
        v = row.get(k)
        meta[k] = "" if v is None else str(v).strip()
    date = row.get("date")
    if date not in (None, ""):
        try:
            meta["date"] = datetime.date.fromisoformat(str(date).strip()).isoformat()
        except ValueError:
            raise DatasetError(f"{where}: field 'date' = {date!r}: not an ISO date (YYYY-MM-DD)") from None
    sp = row.get("hall_setpoint_c")
    if sp not in (None, ""):
        try:
            v = float(sp)
        except (TypeError, ValueError):
            v = math.nan
        if not (math.isfinite(v) and -50.0 <= v <= 100.0):
            raise DatasetError(f"{where}: field 'hall_setpoint_c' = {sp!r}: not a temperature in degC (-50..100)")
        meta["hall_setpoint_c"] = v
    extra = {str(k): str(v) for k, v in row.items() if k not in ("path",) + META_FIELDS and v not in (None, "")}
    name = meta.pop("name") or full.stem
    return RunEntry(str(full), name, extra=extra, **meta)


def read_manifest(path: str | pathlib.Path) -> list[RunEntry]:
    """The runs of a YAML or CSV manifest (paths relative to the manifest's folder)."""
    p = pathlib.Path(path)
    base = p.parent
    text = p.read_text(encoding="utf-8-sig")
    if p.suffix.lower() == ".csv":
        rows = list(csv.DictReader(io.StringIO(text)))
        rows = [{(k or "").strip(): (v or "").strip() for k, v in r.items()} for r in rows]
        where = [f"{p}: line {i + 2}" for i in range(len(rows))]
    else:
        try:
            raw = yaml.load(text, Loader=_TextDates)  # noqa: S506 (a SafeLoader)
        except yaml.YAMLError as exc:
            raise DatasetError(f"{p}: not YAML ({str(exc).splitlines()[0]})") from None
        rows = raw.get("runs") if isinstance(raw, dict) else raw
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise DatasetError(f"{p}: field 'runs' must be a list of mappings with 'path' (and unit, programme, "
                               "date, hall_setpoint_c)")
        where = [f"{p}: runs[{i}]" for i in range(len(rows))]
    if not rows:
        raise DatasetError(f"{p}: the manifest lists no run")
    return [_entry(r, w, base) for r, w in zip(rows, where)]


def _folder(p: pathlib.Path) -> list[RunEntry]:
    """A folder's runs: its manifest's when it holds one (a CSV with a ``path`` column or
    ``manifest.yaml``), else every recording in it, sorted by name."""
    files = sorted(q for q in p.iterdir() if q.is_file())
    manifests = [q for q in files if (q.suffix.lower() == ".csv" and is_manifest(q))
                 or q.name.lower() in ("manifest.yaml", "manifest.yml")]
    if len(manifests) > 1:
        raise DatasetError(f"{p}: folder holds {len(manifests)} manifests ({', '.join(q.name for q in manifests)}); "
                           "give the one to use")
    if manifests:
        return read_manifest(manifests[0])
    found = [q for q in sorted(p.iterdir()) if (q.is_file() and q.suffix.lower() in RECORDING_SUFFIXES)
             or _is_bag_folder(q)]
    if not found:
        raise DatasetError(f"{p}: folder holds no recording (*.csv, *.mcap or bag folders)")
    return [RunEntry(str(q), q.stem) for q in found]


def resolve_runs(sources: Iterable[str]) -> list[RunEntry]:
    """Every run the sources name, in the order given (a folder or glob sorted by name); the
    same file twice and two runs of one name are refused."""
    runs: list[RunEntry] = []
    for src in sources:
        p = pathlib.Path(src)
        if any(ch in src for ch in "*?[") and not p.exists():
            hits = sorted(glob.glob(src))
            if not hits:
                raise DatasetError(f"source {src!r}: the pattern matches no file")
            # a manifest the pattern also matches is no recording
            runs += [RunEntry(h, pathlib.Path(h).stem) for h in hits if not is_manifest(pathlib.Path(h))]
        elif not p.exists():
            raise DatasetError(f"source {src!r}: no such file or folder")
        elif p.is_file() and is_manifest(p):
            runs += read_manifest(p)
        elif p.is_dir() and not _is_bag_folder(p):
            runs += _folder(p)
        else:
            runs.append(RunEntry(str(p), p.stem))
    if not runs:
        raise DatasetError("no recording given")
    seen: dict[str, str] = {}
    for r in runs:
        key = str(pathlib.Path(r.path).resolve())
        if key in seen:
            raise DatasetError(f"run {r.name!r}: file {r.path} is listed twice")
        seen[key] = r.name
    names = [r.name for r in runs]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise DatasetError(f"run name {dupes[0]!r} is used by {names.count(dupes[0])} runs (give each a 'name' "
                           "in a manifest)")
    return runs
