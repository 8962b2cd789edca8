"""numba's inliner with one scope copy per copied function (``tracer.kernel.inline_copies``):
installed, and the IR it copies is the IR numba's own copy makes."""

import copy

import numba
from numba.core import inline_closurecall, ir, untyped_passes
from numba.core.compiler import run_frontend

from tracer.kernel import inline_copies
from tracer.shading.light_tree import tree_sample


def test_installed_on_the_locked_numba():
    """The lock file's numba is one it was written against, so the kernels compile with it."""
    assert numba.__version__.startswith(inline_copies.TESTED)
    assert inline_copies.install()
    assert "__deepcopy__" in vars(ir.Scope)
    assert inline_closurecall.InlineWorker.inline_ir.__name__ == "inline_with_shared_scopes"


def _blocks_copied(function_ir, inlining: bool):
    """Each block of ``function_ir`` deep-copied on its own, as the inliner copies them."""
    if inlining:
        inline_copies._state.inlining = 1
    try:
        duplicate = function_ir.copy()
        duplicate.blocks = {label: copy.deepcopy(b) for label, b in function_ir.blocks.items()}
        return duplicate
    finally:
        inline_copies._state.inlining = 0
        inline_copies._state.scopes = None


def test_a_copy_inside_an_inlining_shares_one_scope_copy():
    """Inside an inlining the copied blocks share one new scope, equal to the original and not
    it; outside one every block copies the scope, as numba does."""
    function_ir = run_frontend(tree_sample.py_func)
    original = {id(b.scope) for b in function_ir.blocks.values()}
    shared = _blocks_copied(function_ir, inlining=True)
    scopes = {id(b.scope) for b in shared.blocks.values()}
    assert len(scopes) == 1 and not scopes & original
    scope = next(iter(shared.blocks.values())).scope
    assert scope == next(iter(function_ir.blocks.values())).scope
    for block, twin in zip(function_ir.blocks.values(), shared.blocks.values(), strict=True):
        assert [str(stmt) for stmt in block.body] == [str(stmt) for stmt in twin.body]
        assert all(assign.target.scope is scope for assign in twin.find_insts(ir.Assign))
    plain = _blocks_copied(function_ir, inlining=False)
    assert len({id(b.scope) for b in plain.blocks.values()}) == len(function_ir.blocks)


def test_a_callee_inlined_three_times_is_translated_once(monkeypatch):
    """One caller's three call sites of an inlined helper run the helper's untyped passes once
    (each site still gets a copy of its IR, so the result is right)."""
    translated = []
    extract = untyped_passes.ExtractByteCode.run_pass

    def counting(self, state):
        translated.append(state.func_id.func_qualname)
        return extract(self, state)

    monkeypatch.setattr(untyped_passes.ExtractByteCode, "run_pass", counting)

    @numba.njit(inline="always")
    def helper(x):
        return 2.0 * x + 1.0

    @numba.njit
    def caller(x):
        return helper(x) + helper(x + 1.0) * helper(x - 1.0)

    assert caller(1.0) == 3.0 + 5.0 * 1.0
    assert translated.count(helper.py_func.__qualname__) == 1
