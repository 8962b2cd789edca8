"""The two decorators every kernel uses.

``error_model="numpy"`` gives IEEE semantics (1/0 = inf, no ZeroDivisionError checks) that the
robust slab test relies on; ``fastmath`` stays off so results are reproducible and error bounds
hold. ``jit_inline`` is for helpers that take arrays: inlining them avoids reference-count
traffic on every call. ``nogil`` lets Python threads run kernels in parallel: we parallelise
with a thread pool (tracer.kernel.threads) rather than numba's parfors, which keeps every kernel
cacheable and the thread count an explicit argument.
"""

from numba import njit

jit = njit(cache=True, error_model="numpy", nogil=True)
jit_inline = njit(cache=True, error_model="numpy", nogil=True, inline="always")
