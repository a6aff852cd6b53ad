"""Benchmarks: time against error for every method with alternatives (not tests)."""
