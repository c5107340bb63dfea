"""Calling a grammar's compiled deriver from the generic round kernels.

The generic kernels (round_kernels.py) are compiled once for every grammar; each grammar's
`advance` (geometry/compiled.py) is compiled in its own module. A generic kernel calls it
through its machine-code address (`native_address`) with `call_native`, numba's own calling
convention (arrays passed as they are, exceptions propagated), so a whole step of rounds
runs in one call without compiling the generic code again per grammar.
"""

from __future__ import annotations

from typing import Any, cast

from numba import typeof, types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def _call_native(typingctx: Any, addr: Any, args: Any) -> Any:
    """call_native(addr, args): the numba function at machine address `addr`, compiled for
    exactly the types of the tuple `args` (native_address), called with them; its int64
    result. An exception it raises propagates to the caller."""
    if not isinstance(addr, types.Integer) or not isinstance(args, types.BaseTuple):
        return None
    argtys: tuple[Any, ...] = tuple(cast(Any, args))
    unpack = cast(Any, cgutils.unpack_tuple)

    def codegen(context: Any, builder: Any, sig: Any, llargs: Any) -> Any:
        fnty = context.call_conv.get_function_type(types.int64, argtys)
        fn = builder.inttoptr(llargs[0], fnty.as_pointer())
        values = unpack(builder, llargs[1], len(argtys))
        status, res = context.call_conv.call_function(builder, fn, types.int64, argtys, values)
        with builder.if_then(status.is_error, likely=False):
            context.call_conv.return_status_propagate(builder, status)
        return res

    return types.int64(addr, args), codegen


call_native: Any = _call_native  # called from kernels only (numba supplies typingctx)


def native_address(dispatcher: Any, args: tuple[Any, ...]) -> int:
    """The machine-code address of numba `dispatcher` compiled for the types of `args` (as
    a call with them from Python would type them; compiled or loaded from its cache)."""
    sig = tuple(cast(Any, typeof)(a) for a in args)
    dispatcher.compile(sig)
    cres = dispatcher.overloads[sig]
    return int(cres.library.get_pointer_to_function(cres.fndesc.mangled_name))
