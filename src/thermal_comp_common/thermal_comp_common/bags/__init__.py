"""rosbag2 MCAP bags without rclpy: reading, writing, repairing, the message definitions and text,
and bags as recordings (to and from the recording CSV)."""
