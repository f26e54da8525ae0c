"""Readers of stereo sequences, one module per layout."""
