"""Kinematics node: closed-form inverse kinematics and Savitzky-Golay velocity estimation per mocap
sample."""
