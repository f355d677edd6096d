"""Whole applications on the batched loop: batch metrics, tune, robustness, calibrate."""
