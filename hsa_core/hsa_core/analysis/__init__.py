"""What a run is judged by: run logs, metrics, the real reference runs, sim-to-real, figures, live
payloads."""
