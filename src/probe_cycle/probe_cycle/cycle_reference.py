"""The reference (zero) cycles that later cycles are measured against, and their storage.

The sphere cycle's errors are differences to the centres of the reference cycle (eq.
5.4-5.10, "i = 1"), which removes the time-invariant geometric errors. The guide bush's
zero is taken at the first cycle (AGP thesis §1). A reference is only ever replaced by a
successful cycle. Stored as JSON (written to a temporary file, then renamed), so a server
restart keeps the zero. A bad file raises :class:`ReferenceFileError` naming the key.
"""
from __future__ import annotations

import json
import math
import os
import pathlib
from dataclasses import dataclass, field

import numpy as np


class ReferenceFileError(ValueError):
    """The reference file is malformed; the message names the key and value."""


@dataclass(frozen=True)
class SphereReference:
    centres_um: np.ndarray         # (4, 3), sphere centres at C = 0, 90, 180, 270
    covariances_um2: np.ndarray    # (4, 3, 3)
    stamp_s: float


@dataclass(frozen=True)
class GuideBushReference:
    position_um: float             # mean skip position in X, um
    uncertainty_um: float          # standard uncertainty of that mean
    stamp_s: float


@dataclass
class ReferenceStore:
    sphere: SphereReference | None = None
    guide_bush: dict[str, GuideBushReference] = field(default_factory=dict)  # per tool pos.

    # ---------------------------------------------------------------- persistence
    def to_dict(self) -> dict:
        out: dict = {"format": "thermal-comp probe reference 1", "guide_bush": {}}
        if self.sphere is not None:
            out["sphere"] = {"centres_um": self.sphere.centres_um.tolist(),
                             "covariances_um2": self.sphere.covariances_um2.tolist(),
                             "stamp_s": self.sphere.stamp_s}
        for name, ref in self.guide_bush.items():
            out["guide_bush"][name] = {"position_um": ref.position_um,
                                       "uncertainty_um": ref.uncertainty_um,
                                       "stamp_s": ref.stamp_s}
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "reference") -> "ReferenceStore":
        def arr(obj, key, shape):
            try:
                a = np.asarray(obj[key], dtype=float)
            except KeyError:
                raise ReferenceFileError(f"{source}: missing key '{key}'") from None
            except (TypeError, ValueError):
                raise ReferenceFileError(f"{source}: '{key}' is not numeric: "
                                         f"{obj[key]!r}") from None
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise ReferenceFileError(f"{source}: '{key}' must be finite with shape "
                                         f"{shape}, got {a.shape}")
            return a

        def num(obj, key):
            try:
                v = float(obj[key])
            except KeyError:
                raise ReferenceFileError(f"{source}: missing key '{key}'") from None
            except (TypeError, ValueError):
                raise ReferenceFileError(f"{source}: '{key}' is not a number: "
                                         f"{obj[key]!r}") from None
            if not math.isfinite(v):
                raise ReferenceFileError(f"{source}: '{key}' is not finite: {v!r}")
            return v

        if not isinstance(data, dict):
            raise ReferenceFileError(f"{source}: expected a JSON object")
        store = cls()
        if "sphere" in data:
            s = data["sphere"]
            store.sphere = SphereReference(arr(s, "centres_um", (4, 3)),
                                           arr(s, "covariances_um2", (4, 3, 3)),
                                           num(s, "stamp_s"))
        gb = data.get("guide_bush", {})
        if not isinstance(gb, dict):
            raise ReferenceFileError(f"{source}: 'guide_bush' must be an object")
        for name, g in gb.items():
            store.guide_bush[name] = GuideBushReference(
                num(g, "position_um"), num(g, "uncertainty_um"), num(g, "stamp_s"))
        return store

    def save(self, path: str | os.PathLike) -> None:
        p = pathlib.Path(path)
        tmp = p.with_suffix(p.suffix + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1))
        os.replace(tmp, p)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ReferenceStore":
        p = pathlib.Path(path)
        if not p.exists():
            return cls()
        try:
            data = json.loads(p.read_text())
        except json.JSONDecodeError as exc:
            raise ReferenceFileError(f"{p}: not valid JSON ({exc})") from None
        return cls.from_dict(data, source=str(p))
