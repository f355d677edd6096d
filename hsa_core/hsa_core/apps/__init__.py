"""Whole applications on the batched loop and their shared argument parsing: tune, robustness,
calibrate."""
