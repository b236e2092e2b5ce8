"""Helpers for launch-free, multi-process tests of exo_has nodes."""
