"""A borrowed matrix view of a flat array: ``matrix(a, start, rows, cols)``.

``a[start:start + rows * cols].reshape((rows, cols))`` in numba calls numba's run-time
reshape helper (``numba_attempt_nocopy_reshape``, an out-of-line C function that works out
the strides) and makes a view that owns a reference to ``a``'s memory (an atomic increment
and decrement). ``matrix`` builds the same C-order view directly: data pointer
``a.data + 8 start``, shape ``(rows, cols)``, strides ``(8 cols, 8)``, no memory owner. It
*borrows* ``a``'s memory, so it must not outlive the call that made it; ``0 <= start`` and
``start + rows * cols <= a.size`` are the caller's to guarantee (no clamping, no check).

Users: the analytic Jacobian's workspace matrices in generated modules
(:mod:`spidersim.diagram.views` re-exports it) and the Newton Jacobian of an algebraic loop
(:func:`spidersim.solver.newton._jac`). Without numba, ``matrix`` is the reshaped slice.
"""
from __future__ import annotations


def _matrix_py(a, start, rows, cols):
    return a[start:start + rows * cols].reshape((rows, cols))


try:
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover - numba is a dependency
    intrinsic = None


if intrinsic is not None:
    @intrinsic
    def matrix(typingctx, a, start, rows, cols):
        """``a[start:start + rows * cols].reshape((rows, cols))`` of a C-contiguous 1-D
        float64 array, borrowing ``a``'s memory (no reference counting, and none of the run-time
        work of ``reshape``): the analytic Jacobian's workspace matrices."""
        if not (isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C"
                and a.dtype == types.float64 and all(isinstance(v, types.Integer) for v in (start, rows, cols))):
            return None
        rettype = types.Array(a.dtype, 2, "C")

        def codegen(context, builder, sig, args):
            arr, lo, r, c = args
            src = context.make_array(sig.args[0])(context, builder, arr)
            lo = context.cast(builder, lo, sig.args[1], types.intp)
            r = context.cast(builder, r, sig.args[2], types.intp)
            c = context.cast(builder, c, sig.args[3], types.intp)
            out = context.make_array(rettype)(context, builder)
            data = cgutils.gep_inbounds(builder, src.data, lo)
            eight = context.get_constant(types.intp, 8)
            context.populate_array(out, data=data, shape=[r, c],
                                   strides=[builder.mul(c, eight), eight],
                                   itemsize=src.itemsize, meminfo=None, parent=None)
            return out._getvalue()

        return rettype(a, start, rows, cols), codegen
else:  # pragma: no cover
    matrix = _matrix_py
