"""Matching the two views and triangulation: correspondences, 3D reconstruction, temporal tracking."""
