"""Borrowed array views for generated diagram modules: ``view(a, start, stop)``.

A generated module hands every kernel its ports, states and modes as 1-D views of the flat
arrays (``x``, ``sig``, ``modes``, ``xdot``, ``p``). numba's ``a[start:stop]`` makes a view
that owns a reference to ``a``'s memory: an atomic ``NRT_incref`` when it is made and an
``NRT_decref`` when it dies, two to four calls per port per kernel call, which numba's
reference-count pruning cannot remove across calls between functions. In the generated
servo right-hand side they were about 100 calls of the 12 kernel calls, most of its cost.

``view`` builds the same view (data pointer ``a.data + start * stride``, length
``stop - start``, ``a``'s stride) with no memory owner: it *borrows* ``a``'s memory, so no
reference count is touched and LLVM sees plain pointer arithmetic. This is safe here because
the view never outlives the call that made it: a generated function makes the views of its
arguments and passes them to kernels, which (by the block contract) write into them and keep
nothing. ``start`` and ``stop`` are literals of the layout with ``0 <= start <= stop <=
a.size`` (the layout sizes the arrays); the view does not clamp them as slicing does.

``matrix(a, start, rows, cols)`` is the same for a ``(rows, cols)`` C-order matrix in a flat
array (the analytic Jacobian's workspace, :mod:`spidersim.diagram.jacobian`).

Without numba (``JIT = False`` modules, interpreted runs) ``view`` is the slice itself and
``matrix`` the reshaped slice.
"""
from __future__ import annotations

# matrix lives with the solver (its Newton takes its Jacobian view the same way: solver/
# imports nothing from diagram/); re-exported here for the generated modules
from ..solver.borrow import _matrix_py, matrix  # noqa: F401


def _view_py(a, start, stop):
    return a[start:stop]


try:
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover - numba is a dependency
    intrinsic = None


if intrinsic is not None:
    @intrinsic
    def view(typingctx, a, start, stop):
        """``a[start:stop]`` of a 1-D array, borrowing ``a``'s memory (no reference
        counting); see the module docstring for when this is safe."""
        if not (isinstance(a, types.Array) and a.ndim == 1
                and isinstance(start, types.Integer) and isinstance(stop, types.Integer)):
            return None
        layout = "C" if a.layout == "C" else "A"
        rettype = types.Array(a.dtype, 1, layout)

        def codegen(context, builder, sig, args):
            arr, lo, hi = args
            src = context.make_array(sig.args[0])(context, builder, arr)
            lo = context.cast(builder, lo, sig.args[1], types.intp)
            hi = context.cast(builder, hi, sig.args[2], types.intp)
            stride = cgutils.unpack_tuple(builder, src.strides, 1)[0]
            out = context.make_array(rettype)(context, builder)
            if layout == "C":
                data = cgutils.gep_inbounds(builder, src.data, lo)
            else:
                byte = builder.mul(lo, stride)
                raw = builder.bitcast(src.data, cgutils.voidptr_t)
                data = builder.bitcast(cgutils.gep_inbounds(builder, raw, byte),
                                       src.data.type)
            context.populate_array(out, data=data, shape=[builder.sub(hi, lo)],
                                   strides=[stride], itemsize=src.itemsize, meminfo=None,
                                   parent=None)
            return out._getvalue()

        return rettype(a, start, stop), codegen

else:  # pragma: no cover
    view = _view_py
