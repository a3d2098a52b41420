"""Visualisation: colour maps for geometry buffers and preview images."""
