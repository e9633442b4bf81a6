"""Evaluation: metrics, pictures, benchmarks."""
