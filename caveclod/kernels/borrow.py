"""Borrowed arrays: the kernels' inner loops without reference counting.

numba counts the references to every array a jitted function binds: a call
with array arguments, or an inlined helper's parameters, adds one to each
array's count on the way in and takes it off on the way out, each an atomic
instruction (``lock incq``, ``lock decq``). In the build's inner loops (a
carried point re-measured, a step of a walk over the original surface)
those pairs took about a quarter of the CPU: ``perf`` on the rough 1M
terrain found 24-27 % of the samples, in every thread, on those two
instructions.

:func:`borrow` gives the same array (data, shape, strides) without its
meminfo, and numba does not count an array that has none. The rule that
makes it safe: the view is used only while the owner is alive, and never
escapes (not returned, not stored). The kernels therefore borrow their own
arguments on entry: the caller holds those for the whole call. An array a
kernel allocates itself is passed to an inner function that borrows it, so
that the allocating frame keeps it alive.
"""

from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def borrow(typingctx, arr):
    """``arr`` without reference counting (module docstring: keep the owner alive)."""
    def codegen(context, builder, sig, args):
        view = context.make_array(sig.args[0])(context, builder, value=args[0])
        view.meminfo = cgutils.get_null_value(view.meminfo.type)
        view.parent = cgutils.get_null_value(view.parent.type)
        return view._getvalue()
    return arr(arr), codegen
