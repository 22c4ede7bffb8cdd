"""Ground floor of the thermal-comp graph: node runtime, topic names, QoS, message and bag
helpers, the recording format, the component names and the metrics.

The names below are ROS-free; the node runtime (``run_node``, ``Param``, QoS, ``TOPIC_*``)
needs rclpy and is imported from ``thermal_comp_common.runtime.node_runtime`` itself.
"""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "recording_csv": ["Recording", "RecordingError", "read_recording_csv", "write_recording_csv"],
    "bags.reader": ["BagContents", "BagReadError", "read_bag"],
    "bags.writer": ["BagWriter", "BagWriteError", "BagIOError"],
    "bags.recording": ["BagRecordingError", "TruncatedBagError", "bag_to_recording", "load_recording",
                       "check_recording"],
    "bags.truncation": ["truncated_bags_allowed"],
    "bags.csv_to_bag": ["CsvImportError", "csv_to_bag"],
    "components": ["LINEAR_COMPONENTS", "ANGULAR_COMPONENTS", "FIVE_AXIS_COMPONENTS"],
    "kinematics": ["TransformInputError", "applied_offsets_in_component_space", "rot_y"],
    "metrics": ["p99", "rmse", "mae", "q_prod"],
    "runtime.domain_ids": ["claim_domain_id"],
    "runtime.blas_threads": ["single_thread_blas"],
    "sensor_readings": ["model_temperatures"],
    "frames": ["MACHINE_BASE_FRAME", "FrameError", "FrameTransform", "frame_tree", "positions_in_root"],
})
