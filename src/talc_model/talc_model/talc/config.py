"""Every parameter of TALC (:class:`TalcConfig`) and the parameter sets of the Blaser thesis.

Defaults are the thesis's values; each choice where the thesis leaves a gap is a field
(docs/talc.md lists them). No rclpy here.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping

from talc_model.adaptive_model import ANGULAR_COMPONENTS, FIVE_AXIS_COMPONENTS
from talc_model.arx.order_selection import CRITERIA


@dataclass
class TalcConfig:
    """Every TALC parameter. Defaults: Table 6.1's fixed values (CP interval 5 min, ACL
    5 um / 15 um/m, n_a max 1, n_b max 10) and Table 6.4's for the varied ones (CP ASAP,
    post-CP interval 2 h, NG 12 x 10 min, update interval 24 h)."""

    component_names: list[str] = field(default_factory=lambda: list(FIVE_AXIS_COMPONENTS))
    #: sensor ids / machine-state keys (or "a - b"); empty = all temperatures of the first update;
    #: ``twin:<node>`` / ``twin:<error>``: a soft sensor of the machine type (``type_model``)
    input_names: list[str] = field(default_factory=list)
    #: the machine type whose NOMINAL twin, stepped online from the inputs TALC receives, gives
    #: the soft sensors ``twin:...`` (a twin preset name or machine YAML; talc_model.type_inputs,
    #: docs/talc.md, "The machine type's physics ..."); "" = none
    type_model: str = ""
    #: TALC's inputs when it starts from a prior of the machine type: ``build_talc_prior`` fits
    #: the prior on them and ``talc_with_prior`` runs on them (e.g. the type's soft sensors
    #: ``twin:<node>``); a run without a prior (the thesis's protocol: calibration phase, order
    #: growth) keeps ``input_names`` (from zero, six soft sensors need a long calibration and
    #: do worse: docs/talc.md, "The machine type's physics ..."). [] = ``input_names`` in both
    type_input_names: list[str] = field(default_factory=list)
    #: time constant of the unit's discrepancy from its type: a prior whose inputs are soft
    #: sensors gets this pole (talc_model.prior.talc.with_discrepancy_pole), so a probe's correction
    #: persists; just under ``max_time_constant_h`` (24 h) so updates keep it admissible
    type_discrepancy_tau_h: float = 23.0
    angular_components: list[str] = field(default_factory=lambda: list(ANGULAR_COMPONENTS))
    model_step_s: float = 300.0            # model / prediction grid (thesis: 5 min)
    # --- Table 6.1
    cp_length_h: float = 0.0               # 0 = ASAP (orders and rank)
    cp_interval_s: float = 300.0           # measurement interval in the CP
    post_cp_interval_h: float = 2.0        # measurement interval after the CP (inf = never)
    ng_interval_min: float = 10.0          # measurement interval in a no-good phase
    acl_linear_um: float = 5.0             # action-control limit, linear errors
    acl_angular_um_per_m: float = 15.0     # action-control limit, angular errors
    ng_measurements: float = 12            # measurements per NG phase (inf = stay in NG)
    update_interval_h: float = 24.0        # maximum time between parameter updates (inf = only after NG)
    na_max: int = 1
    nb_max: int = 10
    # --- order selection and growth
    na_min: int = 1
    nb_min: int = 1
    nb_max_final: int = 10                 # n_b max reached once enough data exist (Table 6.6: 20)
    growth_samples_per_parameter: float = 5.0
    nk: int = 0                            # input delay; 0 includes b0 (thesis examples)
    intercept: bool = False
    criterion: str = "mdl"
    train_fraction: float = 0.6
    reselect_orders_on_update: bool = True  # spec §4.5 suggestion; False = refit with fixed orders
    order_search_exhaustive_limit: int = 4000  # above: coordinate search (order_selection)
    #: an input whose range over the training part of the data is at most this (in its own
    #: unit: K, or 1 for an on/off state) has not varied and cannot be identified: it is left
    #: out of the order search (n_b = 0) and of the calibration phase's rank check until it
    #: has varied. This lets one input list serve every cell: e.g. the MWF state flag of a
    #: cell that has not switched MWF on yet (or never does) costs nothing.
    min_input_range: float = 1e-6
    #: accept a *periodic* update only if the new parameters predict the measured history
    #: (TALC predictor: measurements replace predictions, weighted like the fit) no worse than
    #: the old ones. Updates after a no-good phase are always taken: the old parameters are
    #: known to miss the recent measurements, and gating them slows re-learning after a change.
    update_acceptance: bool = True
    #: at updates, score order candidates with the TALC predictor (state updates at the
    #: measurements) instead of pure simulation over the validation part
    select_with_state_updates: bool = False
    # --- robustness to probe noise (gaps of the thesis; see docs/talc.md "Probe noise")
    #: the CP ends no earlier than this many measured samples per parameter of the largest
    #: candidate model (1 ~ the thesis's "sum of the maximum orders"; 2.5 ends the CP of the
    #: 178 h run after 5.7 h, the thesis reports ~6 h)
    cp_min_samples_per_parameter: float = 2.5
    #: longest time constant a fitted model may have: poles beyond exp(-step / tau) are rejected
    #: (a machine tool's thermal time constants are hours; a pole fitted to noise near 1 makes
    #: the simulation drift like an integrator between the sparse probes); inf = off
    max_time_constant_h: float = 24.0
    #: reject models with complex or negative poles (heat conduction has real poles in (0, 1))
    real_positive_poles: bool = False
    #: reject models with an input whose coefficients sum in absolute value to more than this
    #: many times their net (static) gain: a differentiator fitted to slow data amplifies a
    #: faster input change than any it saw (a hall door: 3 K in 25 min); inf = off
    max_input_gain_ratio: float = math.inf
    # --- weighted least squares
    predicted_weight: float = 0.3          # weight of samples that only carry a prediction (see docs)
    resimulate_history_on_update: bool = False  # regenerate predicted samples with new parameters
    cp_gap_fill: str = "interpolate"       # CP grid samples without a measurement: "interpolate"
    #                                        (linear, between the neighbouring measurements) or
    #                                        "predict" (left out of the first fit, then filled with
    #                                        the fitted model's predictions)
    forgetting_factor: float = 1.0         # weight multiplier per forgetting_period_h of age (1 = off)
    forgetting_period_h: float = 24.0
    history_window_h: float = math.inf     # only samples this recent are fitted
    # --- probing
    probe_duration_s: float = 95.0
    interval_from_cycle_end: bool = True
    uncertainty_window: int = 10
    #: machine-state signals (comma-separated) whose switch (a change by more than 0.5, e.g. the
    #: MWF flag coolant_on, M08/M09, or a speed step of c_speed_rpm) makes one extra probing due ``switch_probe_delay_min`` later, on top
    #: of the schedule: the model gets the step response after a switch wrong in its shape, and
    #: the probe measures it early (docs/talc.md, "A rate state in the observer ..."). "" = off
    switch_probe_input: str = ""
    switch_probe_delay_min: float = 30.0
    #: the model decides when to probe: a probing is due once the model's predicted change of
    #: any component since the last probing exceeds this many times that component's probe noise
    #: (probe_noise_*), no earlier than ``change_probe_min_interval_min`` after it; the regular
    #: post-CP interval stays the longest gap (docs/talc.md, "The model decides when to probe"). inf = off
    change_probe_threshold: float = math.inf
    change_probe_min_interval_min: float = 20.0
    #: the rule spends a probing only while Q_prod over the last 24 h (or since the start), this
    #: probing counted, stays at or above this (a probing budget per day; the schedule and
    #: no-good phases are not limited by it)
    change_probe_min_q_prod_pct: float = 97.5
    # --- state update by a probe (docs/talc.md "State update")
    #: "observer": a probe corrects the whole output history by the Kalman gain of the model's
    #: own dynamics (talc_model.arx.observer; stable for any n_a); "replace": the thesis's
    #: §6.2.2, the probe replaces the newest output only (diverges for some n_a > 1 models)
    state_update: str = "observer"
    #: standard deviation of one probe (Table 5.4: U(k=2) 0.4-0.6 um, 2.3-2.6 um/m)
    probe_noise_linear_um: float = 0.25
    probe_noise_angular_um_per_m: float = 1.2
    #: per component, hold the last probe while the model's prequential score is not better than
    #: holding it (talc_model.probing.hold_fallback; False = always the model's prediction)
    hold_fallback: bool = True

    def __post_init__(self) -> None:
        self.component_names = [str(c) for c in self.component_names]
        self.input_names = [str(c) for c in self.input_names]
        self.type_input_names = [str(c) for c in (self.type_input_names or [])]
        self.angular_components = [str(c) for c in self.angular_components]
        self.switch_probe_input = str(self.switch_probe_input)
        self.type_model = "" if self.type_model is None else self.type_model
        if not isinstance(self.type_model, str):
            raise ValueError(f"TALC config 'type_model': {self.type_model!r} must be a preset name or YAML path")
        for name in ("model_step_s", "cp_interval_s", "ng_interval_min", "probe_duration_s",
                     "forgetting_period_h", "cp_min_samples_per_parameter", "switch_probe_delay_min",
                     "change_probe_min_interval_min", "type_discrepancy_tau_h"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"TALC config '{name}': {v!r} must be a finite number > 0")
        if not isinstance(self.change_probe_threshold, (int, float)) or math.isnan(self.change_probe_threshold) \
                or self.change_probe_threshold <= 0:
            raise ValueError(f"TALC config 'change_probe_threshold': {self.change_probe_threshold!r} must be a "
                             "number > 0 (inf = off)")
        if not (isinstance(self.change_probe_min_q_prod_pct, (int, float)) and 0 <= self.change_probe_min_q_prod_pct
                < 100):
            raise ValueError(f"TALC config 'change_probe_min_q_prod_pct': {self.change_probe_min_q_prod_pct!r} must "
                             "be a number in [0, 100)")
        if math.isfinite(self.change_probe_threshold) and \
                min(self.probe_noise_linear_um, self.probe_noise_angular_um_per_m) <= 0:
            raise ValueError("TALC config: 'change_probe_threshold' counts in probe noise: 'probe_noise_linear_um' "
                             f"{self.probe_noise_linear_um!r} and 'probe_noise_angular_um_per_m' "
                             f"{self.probe_noise_angular_um_per_m!r} must be > 0")
        for name in ("cp_length_h", "post_cp_interval_h", "update_interval_h", "history_window_h",
                     "max_time_constant_h", "min_input_range", "max_input_gain_ratio",
                     "acl_linear_um", "acl_angular_um_per_m", "ng_measurements"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or math.isnan(v) or v < 0:
                raise ValueError(f"TALC config '{name}': {v!r} must be a number >= 0 (inf allowed)")
        if self.max_input_gain_ratio < 1:
            raise ValueError(f"TALC config 'max_input_gain_ratio': {self.max_input_gain_ratio!r} must be >= 1 "
                             "(inf = no bound)")
        if self.post_cp_interval_h == 0 or self.ng_measurements == 0:
            raise ValueError("TALC config 'post_cp_interval_h' and 'ng_measurements' must be > 0")
        for name in ("na_max", "nb_max", "na_min", "nb_min", "nb_max_final", "nk", "uncertainty_window",
                     "order_search_exhaustive_limit"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"TALC config '{name}': {v!r} must be an integer >= 0")
        if self.na_min > self.na_max or self.nb_min > self.nb_max or self.nb_max_final < self.nb_max:
            raise ValueError(f"TALC config: need na_min <= na_max, nb_min <= nb_max <= nb_max_final "
                             f"(got {self.na_min}, {self.na_max}, {self.nb_min}, {self.nb_max}, "
                             f"{self.nb_max_final})")
        if self.criterion not in CRITERIA:
            raise ValueError(f"TALC config 'criterion': {self.criterion!r} is not one of {list(CRITERIA)}")
        if not 0 < self.predicted_weight <= 1:
            raise ValueError(f"TALC config 'predicted_weight': {self.predicted_weight!r} must be in (0, 1]")
        if not 0 < self.forgetting_factor <= 1:
            raise ValueError(f"TALC config 'forgetting_factor': {self.forgetting_factor!r} must be in (0, 1]")
        if not 0.1 <= self.train_fraction <= 0.95:
            raise ValueError(f"TALC config 'train_fraction': {self.train_fraction!r} must be in [0.1, 0.95]")
        if self.state_update not in ("observer", "replace"):
            raise ValueError(f"TALC config 'state_update': {self.state_update!r} is not 'observer' or 'replace'")
        for name in ("probe_noise_linear_um", "probe_noise_angular_um_per_m"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"TALC config '{name}': {v!r} must be a finite number >= 0")
        if self.cp_gap_fill not in ("predict", "interpolate"):
            raise ValueError(f"TALC config 'cp_gap_fill': {self.cp_gap_fill!r} is not 'predict' or 'interpolate'")
        if not self.component_names:
            raise ValueError("TALC config 'component_names': empty")
        if not isinstance(self.hold_fallback, bool):
            raise ValueError(f"TALC config 'hold_fallback': {self.hold_fallback!r} must be true or false")

    @classmethod
    def from_mapping(cls, config: Mapping[str, Any]) -> "TalcConfig":
        """Build from a mapping; a ``preset`` key starts from :data:`PRESETS`; unknown keys raise."""
        config = dict(config)
        preset = config.pop("preset", None)
        values: dict[str, Any] = {}
        if preset is not None:
            if preset not in PRESETS:
                raise ValueError(f"TALC config 'preset': {preset!r} is not one of {sorted(PRESETS)}")
            values.update(PRESETS[preset])
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(config) - known)
        if unknown:
            raise ValueError(f"TALC config: unknown key(s) {unknown} (known: {sorted(known)})")
        values.update(config)
        for k, v in list(values.items()):
            if isinstance(v, str) and v.strip().lower() in ("inf", "infinity", ".inf"):
                values[k] = math.inf
        for name in ("na_max", "nb_max", "na_min", "nb_min", "nb_max_final", "nk", "uncertainty_window",
                     "order_search_exhaustive_limit"):
            v = values.get(name)
            if isinstance(v, float) and v.is_integer():
                values[name] = int(v)
        return cls(**values)

    @property
    def switch_probe_names(self) -> list[str]:
        """The signals of ``switch_probe_input`` (comma-separated, e.g. "coolant_on, c_speed_rpm")."""
        return [n.strip() for n in self.switch_probe_input.split(",") if n.strip()]

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


#: Parameter sets of the thesis (Tables 6.3, 6.4, 6.6, 7.1).
PRESETS: dict[str, dict[str, Any]] = {
    "table_6_4_178h": dict(cp_length_h=0.0, post_cp_interval_h=2.0, ng_interval_min=10.0,
                           ng_measurements=12, update_interval_h=24.0, na_max=5, nb_max=5,
                           nb_max_final=5),
    "table_6_6_144h_mwf": dict(cp_length_h=0.0, post_cp_interval_h=2.0, ng_interval_min=10.0,
                               ng_measurements=12, update_interval_h=12.0, na_max=1, nb_max=10,
                               nb_max_final=20),
    "table_7_1_test_piece": dict(post_cp_interval_h=1.0, ng_interval_min=5.0, ng_measurements=9,
                                 update_interval_h=8.0, na_max=10, nb_max=10, nb_max_final=10),
    "table_6_3_A": dict(cp_length_h=8.5, post_cp_interval_h=10.0, ng_measurements=12, ng_interval_min=30.0),
    "table_6_3_B": dict(cp_length_h=8.5, post_cp_interval_h=2.0, ng_measurements=6, ng_interval_min=30.0),
    "table_6_3_C": dict(cp_length_h=12.0, post_cp_interval_h=2.0, ng_measurements=18, ng_interval_min=5.0),
    "table_6_3_D": dict(cp_length_h=8.5, post_cp_interval_h=3.0, ng_measurements=12, ng_interval_min=10.0),
}


def parse_input(name: str) -> tuple[str, str | None]:
    """'a - b' -> ('a', 'b'); 'a' -> ('a', None) (one factor of :func:`input_signal`)."""
    name = name.strip()
    if name.startswith("(") and name.endswith(")"):
        name = name[1:-1]
    if " - " in name:
        a, b = name.split(" - ", 1)
        return a.strip(), b.strip()
    return name.strip(), None


def input_signal(name: str, signals: Mapping[str, Any]) -> float:
    """Value of the input ``name`` from the raw ``signals``: a signal ``a``, a difference
    ``a - b``, or a product of such factors ``f * (a - b)`` (e.g. the MWF flag times the MWF
    temperature's excess over the hall: the jets' heat flow is on x (T_MWF - T_structure)).
    NaN if a signal is missing; a bad value raises ValueError naming the input."""
    value = 1.0
    for factor in name.split(" * "):
        a, b = parse_input(factor)
        va = signals.get(a, math.nan)
        vb = signals.get(b, 0.0) if b is not None else 0.0
        try:
            value *= float(va) - float(vb)
        except (TypeError, ValueError):
            raise ValueError(f"update_inputs: input '{name}': value {va!r} / {vb!r} is not a number") from None
    return value
