"""A run's record and set-up: run logs, the real reference runs and run profiles."""
