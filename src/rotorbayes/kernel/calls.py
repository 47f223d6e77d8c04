"""Calling a compiled entry point by the address of its machine code.

A numba function that calls another numba function links the callee's code into its own
and has LLVM optimise and translate the whole of it again.  For a parallel batch that
calls the solver once per row, that was the solver a second time in the first compilation
(3.0-3.3 of a first fit's 20 CPU s on 2 cores).  A batch calls its row's entry point
through :func:`caller` instead: an indirect call, with numba's own calling convention, to
the row's code as it was compiled (or loaded from numba's cache) on its own, its address
passed in at run time (:func:`address`), so the batch is a small function to compile and
its cached code holds no address.  One call per row: nothing measurable at run time.
"""

from __future__ import annotations

from numba.core import cgutils
from numba.extending import intrinsic


def caller(sig):
    """An intrinsic ``call(addr, args)`` that calls the compiled function of signature
    ``sig`` whose code is at ``addr`` (an integer from :func:`address`) with the tuple
    ``args``, each cast to the type ``sig`` gives it, and returns its result.

    An error status the callee returns (it raised) is passed on to the caller, as a
    direct call does."""

    @intrinsic
    def call(typingctx, addr, args):
        def codegen(context, builder, signature, llargs):
            addr_v, packed = llargs
            given = signature.args[1]
            vals = [
                context.cast(builder, builder.extract_value(packed, k), given[k], want)
                for k, want in enumerate(sig.args)
            ]
            fnty = context.call_conv.get_function_type(sig.return_type, sig.args)
            fn = builder.inttoptr(addr_v, fnty.as_pointer())
            status, res = context.call_conv.call_function(
                builder, fn, sig.return_type, sig.args, vals
            )
            with cgutils.if_unlikely(builder, status.is_error):
                context.call_conv.return_status_propagate(builder, status)
            return res

        if len(args) != len(sig.args):
            return None
        return sig.return_type(addr, args), codegen

    return call


def address(dispatcher, sig) -> int:
    """The address of the code of ``dispatcher`` compiled for ``sig`` (it must be compiled
    or loaded already), to be called by :func:`caller` ``(sig)``.  Valid as long as the
    dispatcher lives (a module's function: the whole process)."""
    cres = dispatcher.overloads[sig.args]
    return cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)
