"""Controller node: P-satI-D, P-satI-D + gravity cancellation and the task-space PID baseline at a
fixed rate."""
