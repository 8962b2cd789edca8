"""Acceleration structures and ray queries: BVHs, their updates, intersection."""
