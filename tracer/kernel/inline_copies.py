"""Less copying in numba's inliner: one copy of a callee's scope per copy of its IR instead of
one per block, and one translation of a callee per caller.

numba inlines an ``inline="always"`` function by deep-copying the callee's IR block by block
(``InlineWorker.inline_ir``, twice per call site). Each block's copy runs with a memo of its
own, so every block copies the callee's whole scope again: every variable of the function, for
every block. A kernel inlines its vertex shader and traversals, hundreds of blocks and
thousands of variables each, and these copies were about a quarter of its compile.
``install`` makes the blocks of one copy of a function's IR share one copy of its scope, as a
single deep copy of them all would: the same IR, built in a fraction of the time. Nothing else
changes: outside an inlining, and in another copy, a scope is copied as before. The inliner
also translated a callee (bytecode to IR, with the callee's own inlining) again at each of a
caller's call sites; one translation per caller now serves them all, as ``inline_ir`` copies it
before changing anything.
``docs/performance.md`` (Compile time) measures it; the suite's every kernel and image runs
with it.
"""

import copy
import threading

import numba
from numba.core import inline_closurecall, ir

TESTED = ("0.68.",)
"""numba versions whose inliner this was written against; on others ``install`` does nothing."""

_state = threading.local()


def _shared_scope_copy(scope: ir.Scope, memo: dict) -> ir.Scope:
    """``copy.deepcopy(scope)``, or the copy this copy of a function's IR already made of it."""
    shared = getattr(_state, "scopes", None)
    if shared is not None and id(scope) in shared:
        memo[id(scope)] = shared[id(scope)]
        return shared[id(scope)]
    new = ir.Scope.__new__(ir.Scope)
    memo[id(scope)] = new
    if shared is not None:
        shared[id(scope)] = new
    new.__dict__.update(copy.deepcopy(scope.__dict__, memo))
    return new


def _wrap_copy(function_ir_copy):
    def copy_ir(self):
        if getattr(_state, "inlining", 0):
            _state.scopes = {}  # a new copy of a function's IR: its own scope copies
        return function_ir_copy(self)

    return copy_ir


def _wrap_inline_ir(inline_ir):
    def inline_with_shared_scopes(self, *args, **kwargs):
        outer = getattr(_state, "scopes", None)
        _state.inlining = getattr(_state, "inlining", 0) + 1
        _state.scopes = None
        try:
            return inline_ir(self, *args, **kwargs)
        finally:
            _state.inlining -= 1
            _state.scopes = outer

    return inline_with_shared_scopes


def _wrap_untyped_passes(run_untyped_passes):
    def untyped_once_per_caller(self, func, enable_ssa=False):
        # An InlineWorker serves one caller's compile (its flags and locals): a callee inlined
        # at several call sites is translated once, and inline_ir copies it for each.
        done = self.__dict__.setdefault("_tilerender_untyped", {})
        key = (func, enable_ssa)
        if key not in done:
            done[key] = run_untyped_passes(self, func, enable_ssa)
        return done[key]

    return untyped_once_per_caller


def install() -> bool:
    """Patch numba's inliner (once per process); whether it is patched."""
    if getattr(ir.Scope, "_tilerender_shared_copies", False):
        return True
    worker = getattr(inline_closurecall, "InlineWorker", None)
    if (
        not numba.__version__.startswith(TESTED)
        or worker is None
        or "__deepcopy__" in vars(ir.Scope)
    ):
        return False
    ir.Scope.__deepcopy__ = _shared_scope_copy
    ir.FunctionIR.copy = _wrap_copy(ir.FunctionIR.copy)
    worker.inline_ir = _wrap_inline_ir(worker.inline_ir)
    worker.run_untyped_passes = _wrap_untyped_passes(worker.run_untyped_passes)
    ir.Scope._tilerender_shared_copies = True
    return True
