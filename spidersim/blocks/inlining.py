"""Kernels that LLVM inlines into the generated system function: ``njit_inlinable``.

A generated diagram module (:mod:`spidersim.diagram.codegen`) calls every block's kernels
from its system function. numba compiles each kernel once (and caches it) and links a copy
of its LLVM code into every caller, whose optimiser decides whether to inline it. For most
small kernels it did not (a loop over a port's width, vectorised when compiled on its own,
makes ``Gain.output`` 425 LLVM instructions; ``Sum``, ``Saturation`` 230-240), and then the
call passes every array argument as its seven fields on the stack (the servo's
``DCMotor.derivative`` call: 7 arrays and 5 numbers, about 60 stores) and tests a status
word on return; ``outputs``, which calls them, was not inlined either. Measured on the servo
(``tools/bench_rhs.py``): one derivatives evaluation 43 ns, outputs 22 ns, against 5.7 ns
for the same equations written by hand behind the same pointer.

numba's own ``inline='always'`` copies the kernel's IR into every call site and types it
again there: the servo's evaluation then costs 11 ns, but compiling the diagram's module
took 6 s of CPU instead of 1 s (most in copying IR), too slow for a new diagram. Here the
kernel is compiled once as before, and the copy of its LLVM function that numba links into
callers is given the ``alwaysinline`` attribute: every caller inlines the already optimised
body, in which the port widths and offsets (literals of the layout) then become constants.
Servo: 10.7 ns per derivatives evaluation, 6.9 ns per outputs evaluation, compile time
unchanged. Kernels larger than :data:`INLINE_MAX_INSTRUCTIONS` (the multibody dynamics)
stay calls: inlining them would multiply LLVM's work for little gain.

The attribute changes where the machine code sits, not what it computes: without
``fastmath`` LLVM neither reassociates nor contracts floating-point operations when it
inlines, so results are bit for bit those of the calls (checked by
``tools/check_loop_identical.py`` on the servo, the ball, the algebraic loop and
``spider.yaml``).
"""
from __future__ import annotations

#: the largest kernel (LLVM instructions of its function as compiled on its own, loops
#: over port widths vectorised) that :func:`njit_inlinable` marks ``alwaysinline``
INLINE_MAX_INSTRUCTIONS = 1000


def mark_alwaysinline(cres, limit=INLINE_MAX_INSTRUCTIONS):
    """Give the LLVM function of the compile result ``cres`` the ``alwaysinline``
    attribute in the module numba links into its callers, when it has at most ``limit``
    instructions. Returns whether it did."""
    try:
        mod = cres.library._get_module_for_linking()
        fn = mod.get_function(cres.fndesc.llvm_func_name)
    except (AttributeError, NameError, RuntimeError):   # numba internals changed: no-op
        return False
    size = sum(1 for b in fn.blocks for _ in b.instructions)
    if size > limit:
        return False
    fn.add_function_attribute("alwaysinline")
    return True


try:
    from numba.core.registry import CPUDispatcher as _CPUDispatcher

    class _InlinableDispatcher(_CPUDispatcher):
        """numba's CPU dispatcher; each compiled function (fresh or loaded from numba's
        cache) is marked by :func:`mark_alwaysinline` before any caller links it."""

        def add_overload(self, cres):
            super().add_overload(cres)
            mark_alwaysinline(cres)

    def njit_inlinable(f):
        """``numba.njit(cache=True, nogil=True, error_model="numpy")(f)`` whose compiled
        function LLVM inlines into every compiled caller when it is small (see the module
        docstring)."""
        disp = _InlinableDispatcher(py_func=f, locals={}, targetoptions=dict(
            nopython=True, nogil=True, error_model="numpy", boundscheck=None))
        disp.enable_caching()
        return disp
except ImportError:  # pragma: no cover - numba is a dependency
    def njit_inlinable(f):
        return f
