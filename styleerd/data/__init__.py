"""Datasets -> labelled clips -> causal per-frame features -> cached, split, windowed."""
