"""Evaluation: colour and metrics, the quality knob, and the benchmark's measuring functions."""
