"""hsa_live: the running graph served to Foxglove over WebSocket on localhost (live view)."""
