"""Accuracy and latency figures of runs, as tables and JSON."""
