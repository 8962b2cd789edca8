"""Borrowed array views: arrays that kernels can pass around without reference counting.

numba reference-counts every array it passes to a function, with atomic operations, even to a
function it inlines. In a traversal called once per ray that is ~10 atomic operations per ray:
measured, 40% of the ray-casting time on the Cornell box. A *borrowed* view shares the data,
shape and strides of an array but has no memory-info pointer, so numba's increments and
decrements become no-ops that LLVM removes.

Rule: borrow only arrays that outlive the kernel call, i.e. the kernel's own arguments. Never
borrow an array the kernel allocates, and never return or store a borrowed view.
"""

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def borrowed(typingctx, array):
    """A view of ``array`` that holds no reference to it (see the module docstring)."""
    if not isinstance(array, types.Array):
        return None

    def codegen(context, builder, signature, args):
        source = context.make_array(array)(context, builder, value=args[0])
        view = context.make_array(array)(context, builder)
        view.data = source.data
        view.shape = source.shape
        view.strides = source.strides
        view.itemsize = source.itemsize
        view.nitems = source.nitems
        view.meminfo = cgutils.get_null_value(view.meminfo.type)
        view.parent = cgutils.get_null_value(view.parent.type)
        return view._getvalue()

    return array(array), codegen
