"""ROS 2 glue shared by the hsa-ros nodes: QoS, parameters, diagnostics, message conversion, node
runner, the ROS process environment and the venv launcher."""
