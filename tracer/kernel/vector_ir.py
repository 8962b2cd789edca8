"""What the kernels' hand-written LLVM vector code shares (numba does not vectorise short
scalar runs itself): the check that an argument is a matrix the code may load rows of, the
address of a row, and a scalar broadcast to every lane."""

from llvmlite import ir
from numba import types


def is_c_matrix(array_type: types.Type, dtype: types.Type) -> bool:
    """Whether ``array_type`` is a C-contiguous 2D array of ``dtype`` (whose rows are
    contiguous bytes)."""
    return (
        isinstance(array_type, types.Array)
        and array_type.dtype == dtype
        and array_type.ndim == 2
        and array_type.layout == "C"
    )


def row_address(context, builder, array_type, array, row, row_type) -> ir.Value:
    """An ``i8*`` to the first byte of row ``row`` of the C matrix ``array``."""
    matrix = context.make_array(array_type)(context, builder, value=array)
    offset = builder.mul(
        context.cast(builder, row, row_type, types.int64),
        builder.extract_value(matrix.strides, 0),
    )
    return builder.gep(builder.bitcast(matrix.data, ir.IntType(8).as_pointer()), [offset])


def splat(builder, vector: ir.VectorType, x: ir.Value) -> ir.Value:
    """``x`` in every lane of a ``vector``."""
    lane0 = builder.insert_element(
        ir.Constant(vector, ir.Undefined), x, ir.Constant(ir.IntType(64), 0)
    )
    mask = ir.Constant(ir.VectorType(ir.IntType(32), vector.count), 0)
    return builder.shuffle_vector(lane0, lane0, mask)
