"""Whole jobs: a file in, files out. Each pipeline knows nothing of batches."""
