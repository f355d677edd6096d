"""The servo driver's supervision as a pure state machine."""
