"""MCAP record and replay of hsa-ros topics, and offline analysis of recorded runs."""
