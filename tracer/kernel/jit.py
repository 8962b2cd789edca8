"""The two decorators every kernel uses.

``error_model="numpy"`` gives IEEE semantics (1/0 = inf, no ZeroDivisionError checks) that the
robust slab test relies on; ``fastmath`` stays off so results are reproducible and error bounds
hold. ``jit_inline`` is for helpers that take arrays: inlining them avoids reference-count
traffic on every call. ``nogil`` lets Python threads run kernels in parallel: we parallelise
with a thread pool (tracer.kernel.threads) rather than numba's parfors, which keeps every kernel
cacheable and the thread count an explicit argument.
"""

from types import FunctionType

from numba import njit

from tracer.kernel import inline_copies

inline_copies.install()

jit = njit(cache=True, error_model="numpy", nogil=True)
jit_inline = njit(cache=True, error_model="numpy", nogil=True, inline="always")


def with_globals(func: FunctionType, **names: object) -> FunctionType:
    """``func`` seeing ``names`` as module globals, for a kernel built per variant that calls a
    variant's jitted helper. A closure over the helper would defeat numba's on-disk cache: its
    key pickles the closure's cells, and a dispatcher pickles differently in every process.
    Globals are resolved at compile time and are not in the key, so the variants still need
    closure constants of their own to tell their cache entries apart."""
    scope = {**func.__globals__, **names}
    built = FunctionType(func.__code__, scope, func.__name__, func.__defaults__, func.__closure__)
    built.__qualname__ = func.__qualname__
    built.__doc__ = func.__doc__
    built.__module__ = func.__module__
    return built
