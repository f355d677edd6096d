"""The controller: control laws, the supervised tick, its supervision and input validation."""
