"""The one dispatch on a prior's ``model_kind``: the run's TALC, AGP or CD model started from a
prior, for the node, ``replay --prior`` and the benches. No rclpy here. docs/prior.md.
"""
from __future__ import annotations

from typing import Any, Mapping

from talc_model.prior.agp import agp_with_prior
from talc_model.prior.cd import cd_with_prior
from talc_model.prior.common import PriorError
from talc_model.prior.integrity import check_prior, check_run
from talc_model.prior.talc import talc_with_prior


def model_from_prior(kind: str, config: Mapping[str, Any], prior: Mapping[str, Any]):
    """The run's model of ``kind`` started from ``prior`` (TALC, AGP or CD; its ``model_kind``,
    soft-sensor twin and inputs must be the run's: talc_model.prior.integrity.check_run)."""
    prior_kind = prior.get("model_kind", "talc")
    if prior_kind != kind:
        raise PriorError(f"prior: 'model_kind' is {prior_kind!r}, the model is {kind!r}")
    check_run(prior, config)
    if kind == "talc":          # its own model class checks its ARX models when it installs them
        return talc_with_prior(config, prior)
    if kind not in ("agp", "cd"):
        raise PriorError(f"prior: no prior for model kind {kind!r} (talc, agp, cd)")
    check_prior(prior)          # the GPs / diagrams on the held-out training programme
    return agp_with_prior(config, prior) if kind == "agp" else cd_with_prior(config, prior)
