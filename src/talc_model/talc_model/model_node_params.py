"""The model node's ROS parameters (names, defaults, descriptions, ranges): one table that
:mod:`talc_model.talc_model_node` declares and the docs and tests read. No rclpy."""
from __future__ import annotations

from thermal_comp_common.runtime.node_runtime import Param

from talc_model.loop.applied_compensation import MODES

MODEL_NODE_PARAMS = [
    Param("model_kind", "talc", "adaptive model", choices=("talc", "agp", "cd")),
    Param("model_config", "", "YAML file with the model's configuration (empty = defaults)"),
    Param("state_path", "", "JSON file for the model state (resumed at start; empty = no persistence); "
          "a relative path lives under $XDG_STATE_HOME/thermal-comp (default ~/.local/state/thermal-comp)"),
    Param("pretrained_path", "", "state of a trained model to start from when state_path has none"),
    Param("prior_path", "", "TALC prior (thermal-comp prior) to start from when state_path has none"),
    Param("save_period_s", 3600.0, "save the state at least this often (model time), s", 1.0, 1e7),
    Param("artefact", "sphere", "probing artefact", choices=("sphere", "guide_bush")),
    Param("tool_position", "", "lathe: tool position probed (e.g. GB)"),
    Param("points_per_indexing", 0, "touch points per C indexing; 0 = the server's default", 0, 100),
    Param("probe_timeout_s", 0.0, "cycle timeout in simulated time sent with the goal; 0 = server default",
          0.0, 86400.0),
    Param("probe_result_wait_s", 600.0, "wall-clock wait for a probing result before the cycle is "
          "cancelled and counted as failed, s", 0.1, 86400.0),
    Param("action_server_wait_s", 10.0, "wall-clock wait for the probe_cycle action server, s", 0.0, 3600.0),
    Param("offsets_wait_s", 2.0, "wall-clock wait for the bridge's offsets answering t_k before a "
          "probe starts or a periodic save runs (only once offsets have been seen), s", 0.0, 600.0),
    Param("applied_compensation", "offsets", "how the applied compensation is known", choices=MODES),
    Param("lockstep_participant", False, "publish SimSync for t_k after the prediction for t_k"),
    Param("machine_state_wait_s", 10.0, "lock-step: wall-clock wait for the machine state of an instant "
          "before its temperatures are modelled with the last inputs, s", 0.0, 3600.0),
    Param("max_stamp_ahead_s", 0.0, "refuse messages stamped more than this ahead of the node's clock, s; "
          "0 = 60 s on wall time, 3600 s with use_sim_time (data may precede its /clock by a step)",
          0.0, 86400.0),
    Param("online_learning", False, "online learning: offer the adopt_prior service and keep the run's "
          "history to warm a learned prior's model (memory grows with the run, up to history_max_instants)"),
    Param("audit_path", "", "online learning: audit file (JSON lines) of adopted or refused priors; empty = log only"),
    Param("warm_events_per_instant", 200, "online learning: history events a new prior's model is warmed over "
          "per modelled instant (bounds the pause of one instant)", 1, 10**7),
    Param("history_max_instants", 100000, "online learning: instants of the run kept to warm a new prior's model",
          0, 10**8),
]
