"""Helpers for the numba kernels."""

from numba.core import types
from numba.extending import intrinsic


@intrinsic
def as_runtime(typingctx, value):
    """value typed as an ordinary bool or int, not as a compile-time constant. numba compiles a kernel anew for
    each constant a caller passes it (source_terms(..., True, False, ...) and (..., flag, True, ...) are two
    machine codes, each seconds to build): flags and counts passed through this share one compiled kernel."""
    sig = types.unliteral(value)(value)

    def codegen(context, builder, signature, args):
        return context.cast(builder, args[0], signature.args[0], signature.return_type)

    return sig, codegen
