#!/bin/bash
# Record a bag from the running graph: machine_sim (twin) -> temperature_publisher (sensors)
# -> talc_model (+ probe_cycle server probing the twin) -> cnc_bridge (twin backend), all in
# lock-step simulated time, recorded by `thermal-comp record` (default topics).
#   usage: bags/record_graph.sh OUT_BAG MACHINE SCENARIO HOURS SENSOR_CONFIG
#   e.g.   bags/record_graph.sh bags/graph_nmv5000_load_case_A_12h nmv5000 load-case-A 12.0 nmv5000
#   MODEL_ARGS / BRIDGE_ARGS: extra "-p name:=value" arguments of talc_model / cnc_bridge, e.g.
#   MODEL_ARGS="-p model_kind:=agp -p artefact:=guide_bush -p tool_position:=GB" for the lathe.
# Uses its own ROS_DOMAIN_ID (default 97) and logs to $LOG_DIR (default a temp dir).
set -eu
cd "$(dirname "$0")/.."
PY=.venv/bin/python
OUT=$1 MACHINE=$2 SCENARIO=$3 HOURS=$4 SENSORS=$5
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-97} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
LOG_DIR=${LOG_DIR:-$(mktemp -d)}
mkdir -p "$LOG_DIR"
export ROS_LOG_DIR=$LOG_DIR
SIM="-p use_sim_time:=true"
NODES=()
REC=
cleanup() {   # stop what this script started (by pid): the nodes first, the recorder last
  [ ${#NODES[@]} -gt 0 ] && kill -INT "${NODES[@]}" 2>/dev/null || true
  [ ${#NODES[@]} -gt 0 ] && wait "${NODES[@]}" 2>/dev/null || true
  [ -n "$REC" ] && kill -INT "$REC" 2>/dev/null && wait "$REC" 2>/dev/null || true
}
trap cleanup EXIT
$PY -m thermal_comp.bags.record_cli "$OUT" > "$LOG_DIR/record.log" 2>&1 & REC=$!
$PY -m thermal_sensors.temperature_publisher_node --ros-args -r __node:=sensors -p source:=twin \
    -p sensor_config:="$SENSORS" -p lockstep_participant:=true $SIM > "$LOG_DIR/sensors.log" 2>&1 & NODES+=($!)
$PY -m probe_cycle.probe_cycle_node --ros-args -p backend:=twin $SIM > "$LOG_DIR/probe.log" 2>&1 & NODES+=($!)
$PY -m talc_model.talc_model_node --ros-args -r __node:=talc_model -p lockstep_participant:=true $SIM ${MODEL_ARGS:-} \
    > "$LOG_DIR/model.log" 2>&1 & NODES+=($!)
$PY -m cnc_bridge.cnc_bridge_node --ros-args -r __node:=cnc_bridge -p backend:=twin -p lockstep:=true $SIM ${BRIDGE_ARGS:-} \
    > "$LOG_DIR/bridge.log" 2>&1 & NODES+=($!)
# machine_sim re-sends an instant until every participant acknowledged it, so late starters
# are fine; the recorder (not a participant) only needs to be up: wait for its bag.
for _ in $(seq 100); do [ -f "$OUT/metadata.yaml" ] && break; sleep 0.1; done
sleep 2
$PY -m thermal_twin.machine_sim_node --ros-args -p machine:="$MACHINE" -p scenario:="$SCENARIO" \
    -p hours:="$HOURS" -p "lockstep_participants:=['sensors','talc_model','cnc_bridge']" \
    -p shutdown_when_done:=true > "$LOG_DIR/machine_sim.log" 2>&1
cleanup
trap - EXIT
echo "recorded $OUT (logs in $LOG_DIR)"
