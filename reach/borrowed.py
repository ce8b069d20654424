"""Arrays handed to compiled loops without reference counting.

Numba counts references to every array it binds: each call of a compiled function (inlined or not) and each
unpacking of a tuple adds one to every array inside and takes it away again, with an atomic instruction. The
filter's decision (:mod:`softreach.filters.compiled`) hands tuples of about seventy arrays (the table, the cells,
the work space) to its kernels several times a row, and ``perf`` put about 28 % of a certified row's time in
``NRT_incref`` / ``NRT_decref``.

:func:`borrowed` returns the same arrays (same data, shape and strides) without an owner, as :func:`numba.carray`
makes them from a pointer; numba skips counting such arrays. It is sound only for arrays that outlive every use
of the borrowed copy: **borrow only a compiled function's arguments** (the Python caller holds them until the
call returns), never an array the function allocates, and never return or store a borrowed array.
"""

from __future__ import annotations

from numba.core import types
from numba.extending import intrinsic


def _borrow_value(context, builder, typ, value):
    if isinstance(typ, types.Array):
        src = context.make_array(typ)(context, builder, value)
        out = context.make_array(typ)(context, builder)
        # meminfo and parent null: an unowned array, as numba.carray makes
        context.populate_array(out, data=src.data, shape=src.shape, strides=src.strides, itemsize=src.itemsize,
                               meminfo=None)
        return out._getvalue()
    if isinstance(typ, types.BaseTuple):
        items = [_borrow_value(context, builder, t, builder.extract_value(value, i)) for i, t in enumerate(typ)]
        return context.make_tuple(builder, typ, items)
    return value


@intrinsic
def borrowed(typingctx, value):
    """``value`` (an array, or a tuple of arrays and scalars, nested) with every array unowned: the same type and
    data, no reference counting. Only for a compiled function's own arguments (the module docstring)."""

    def codegen(context, builder, signature, args):
        return _borrow_value(context, builder, signature.args[0], args[0])

    return value(value), codegen
