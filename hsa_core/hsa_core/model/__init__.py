"""The model of the planar HSA robot: parameters, kinematics, dynamics, actuation, wiring,
integration."""
