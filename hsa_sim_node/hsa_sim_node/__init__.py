"""Simulator node replacing the hardware: emulated MX-28 bus on a pseudo-terminal and mocap poses
from the JAX model."""
