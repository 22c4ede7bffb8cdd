"""The compensated NMV5000 cell on the twin: ``ROS_DOMAIN_ID=42 ros2 launch thermal_comp nmv5000_twin.launch.py``.

The cell file installed to ``share/thermal_comp/config/cells/nmv5000_twin.yaml``, started by
``cell.launch.py`` (equivalent to ``thermal-comp launch config/cells/nmv5000_twin.yaml``). The
cell runs on domain 42 and its bridge is a managed node, so the launch process must be on 42
too (launch_ros sends the bridge's transitions from its own node); ``namespace:=`` and
``domain_id:=`` pass through to ``cell.launch.py``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource


def generate_launch_description():
    share = get_package_share_directory("thermal_comp")
    return LaunchDescription([
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(os.path.join(share, "launch", "cell.launch.py")),
            launch_arguments={"cell_file": os.path.join(share, "config", "cells", "nmv5000_twin.yaml")}.items()),
    ])
