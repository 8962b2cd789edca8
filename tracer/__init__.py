"""tilerender's numerical core: scene compilation, BVH, intersection, sampling, path tracing.

Nothing in this package knows about Ray, HTTP or processes. Importing it points numba's on-disk
cache at one directory that every process of this user shares (see
:mod:`tracer.kernel.numba_cache`), so Ray workers and CLI runs reuse each other's compiled kernels.
"""

from tracer.kernel import numba_cache

numba_cache.configure()
