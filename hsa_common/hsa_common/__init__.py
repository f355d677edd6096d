"""ROS 2 glue shared by the hsa-ros nodes: QoS, parameters, diagnostics, node runner, and the venv launcher."""
