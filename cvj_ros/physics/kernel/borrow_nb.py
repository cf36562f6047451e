"""Reference-count-free array views for the compiled hot loops.

numba hands an array to a function it does not inline together with its NRT meminfo, and
the callee increments and decrements that reference count around its body: two ``lock``
instructions per array argument per call. The integration loops reach the rhs, the
sections and the engine/load models through such calls, with up to 20 arrays each; on
this machine (2-core AMD EPYC) perf put 40 % of a loop over ``section`` on the instructions
right after ``lock incq``/``lock decq``, and borrowing took 27-31 % off ``section`` and the
rhs (docs/solvers.md "Borrowed arrays").

``borrowed(a)`` is a view of array ``a`` (same data, shape and strides) whose meminfo and
parent are NULL, for which numba's incref/decref are a null test; ``borrowed_all(tup)``
does it to every array of a tuple and passes other items through. An entry point called
from Python borrows its array arguments once, so everything below it runs without atomics.
The view does not keep the array alive: borrow only arguments (the caller holds them for
the whole call), never a temporary, and never return or store a view. The arithmetic is the
same code, so the bytes do not change.
"""
from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


def _borrow_value(context, builder, typ, value):
    if not isinstance(typ, types.Array):
        return value
    src = context.make_array(typ)(context, builder, value=value)
    dst = context.make_array(typ)(context, builder)
    dst.meminfo = cgutils.get_null_value(dst.meminfo.type)
    dst.parent = cgutils.get_null_value(dst.parent.type)
    dst.nitems = src.nitems
    dst.itemsize = src.itemsize
    dst.data = src.data
    dst.shape = src.shape
    dst.strides = src.strides
    return dst._getvalue()


@intrinsic
def borrowed(typingctx, arr):
    """View of array ``arr`` without a reference count (meminfo and parent NULL)."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, sig, args):
        return _borrow_value(context, builder, arr, args[0])

    return arr(arr), codegen


@intrinsic
def borrowed_all(typingctx, tup):
    """The tuple ``tup`` with every array replaced by ``borrowed(array)``."""
    if not isinstance(tup, types.BaseTuple):
        return None

    def codegen(context, builder, sig, args):
        items = [_borrow_value(context, builder, typ, builder.extract_value(args[0], i))
                 for i, typ in enumerate(tup.types)]
        return context.make_tuple(builder, tup, items)

    return tup(tup), codegen


#: largest stack_zeros_2d (doubles): 32 KiB, far below any thread's stack (a driveline of
#: 20 sections needs (9 + 20) * 40 = 1160); larger requests are the caller's to refuse
STACK_MAX_DOUBLES = 4096


@intrinsic
def stack_zeros_2d(typingctx, rows, cols):
    """A zeroed (rows, cols) float64 C array in the calling function's stack frame, without a
    meminfo: no NRT allocation, free and atomic reference counts (``np.zeros`` of a small
    scratch was ~0.1 us of a ~0.25 us ``rhs_nb.jac``). Valid until the caller returns, as a
    borrowed view: never return or store it. Only for sizes <= STACK_MAX_DOUBLES (the caller
    checks; a dynamic ``alloca`` of an inlined caller is released by LLVM's stacksave /
    stackrestore around the inlined body)."""
    if not (isinstance(rows, types.Integer) and isinstance(cols, types.Integer)):
        return None
    arrty = types.Array(types.float64, 2, 'C')

    def codegen(context, builder, sig, args):
        from numba.np.arrayobj import populate_array
        intp = context.get_value_type(types.intp)
        r = context.cast(builder, args[0], sig.args[0], types.intp)
        c = context.cast(builder, args[1], sig.args[1], types.intp)
        count = builder.mul(r, c)
        ptr = builder.alloca(context.get_value_type(types.float64), size=count)
        itemsize = intp(8)
        cgutils.memset(builder, ptr, builder.mul(count, itemsize), 0)
        ary = context.make_array(arrty)(context, builder)
        populate_array(ary, data=ptr,
                       shape=cgutils.pack_array(builder, [r, c]),
                       strides=cgutils.pack_array(builder, [builder.mul(c, itemsize), itemsize]),
                       itemsize=itemsize, meminfo=None)
        return ary._getvalue()

    return arrty(rows, cols), codegen
