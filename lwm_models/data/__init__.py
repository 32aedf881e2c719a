"""Benchmark data: game splits and the trajectory dataset."""
