"""Arithmetic shared by compilation and kernels: portable sums, vectors, random numbers."""
