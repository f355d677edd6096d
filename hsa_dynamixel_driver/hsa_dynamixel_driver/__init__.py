"""Dynamixel driver: 4 MX-28 servos over Protocol 2.0 with one sync read and one sync write per
cycle, limits and torque safety."""
