"""What a run is judged by: metrics, sim-to-real, figures, the workspace map, live payloads."""
