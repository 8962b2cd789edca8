"""numba infrastructure: decorators, the on-disk cache, threads, borrowed views."""
