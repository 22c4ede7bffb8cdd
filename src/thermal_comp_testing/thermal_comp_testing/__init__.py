"""Test support of thermal-comp: the pytest plugin every package's tests run under.

``thermal_comp_testing.pytest_plugin`` is loaded by pytest through the ``pytest11`` entry
point (``pytest`` in the repository and ``colcon test`` alike); it gives each test process an
isolated ROS 2 environment, the ``slow``/``ros`` markers and the fixtures ``ros_domain_id``,
``venv_bin``, ``shared_dir`` and ``ros_context``. Nothing here is imported by tests directly.
"""
