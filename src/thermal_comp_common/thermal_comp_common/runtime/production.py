"""Whether this process belongs to a production cell: the cell launcher sets
``THERMAL_COMP_PRODUCTION=1`` for every process of a cell whose file says ``production: true``,
and the CNC-facing processes then refuse open access (a bridge without ``security_required``,
a CNC emulator with ``--security optional`` and no client trust list). docs/security.md.
"""
from __future__ import annotations

import os
from typing import Mapping

#: the environment variable that marks a production cell's processes
PRODUCTION_ENV = "THERMAL_COMP_PRODUCTION"


def production_mode(env: Mapping[str, str] | None = None) -> bool:
    """True when ``env`` (default: this process's environment) marks a production cell."""
    value = (os.environ if env is None else env).get(PRODUCTION_ENV, "").strip().lower()
    return value in ("1", "true", "yes")
