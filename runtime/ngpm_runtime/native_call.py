"""Calling a grammar's compiled deriver from the generic round kernels; a run's numpy
Generator in them by address.

The generic kernels (round_kernels.py) are compiled once for every grammar; each grammar's
`advance` (geometry/compiled.py) is compiled in its own module. A generic kernel calls it
through its machine-code address (`native_address`) with `call_native`, numba's own calling
convention (arrays passed as they are, exceptions propagated), so a whole step of rounds
runs in one call without compiling the generic code again per grammar. A kernel takes
the run's Generator as `generator_addresses` and makes numba's Generator of them with
`generator_at`: passing the Generator object costs ~12 us a call (numba unboxes it through
ctypes), the addresses ~0.1 us; the draws and the state are the same.
"""

from __future__ import annotations

import ctypes
from typing import Any, cast

import numpy as np
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


@intrinsic
def _generator_at(typingctx: Any, addrs: Any) -> Any:
    """generator_at(addrs): numba's np.random.Generator over the bit generator whose ctypes
    interface is at addrs (generator_addresses); it draws what the Python Generator would
    draw and advances the same state. No Python object: it is not returned or boxed."""
    if not (isinstance(addrs, types.Array) and isinstance(addrs.dtype, types.Integer)):
        return None
    gen_t = types.NumPyRandomGeneratorType("NumPyRandomGeneratorType")
    bit_t = types.NumPyRandomBitGeneratorType("NumPyRandomBitGeneratorType")
    proxy, null, gep = (
        cast(Any, f)
        for f in (cgutils.create_struct_proxy, cgutils.get_null_value, cgutils.gep_inbounds)
    )

    def codegen(context: Any, builder: Any, sig: Any, llargs: Any) -> Any:
        arr = context.make_array(sig.args[0])(context, builder, llargs[0])
        bit = proxy(bit_t)(context, builder)
        bit.parent = null(bit.parent.type)
        names = ("state_address", "state", "fnptr_next_uint64", "fnptr_next_uint32",
                 "fnptr_next_double", "bit_generator")  # fmt: skip
        for i, name in enumerate(names):  # int64 items into uintp fields: the same width
            setattr(bit, name, builder.load(gep(builder, arr.data, i)))
        gen = proxy(gen_t)(context, builder)
        gen.bit_generator = bit._getvalue()
        gen.meminfo = null(gen.meminfo.type)
        gen.parent = null(gen.parent.type)
        return gen._getvalue()

    return gen_t(addrs), codegen


generator_at: Any = _generator_at  # called from kernels only


def generator_addresses(rng: np.random.Generator) -> np.ndarray:
    """generator_at's argument for numpy Generator `rng`: its bit generator's ctypes
    interface as int64 addresses (state address, state, next_uint64, next_uint32,
    next_double, bit_generator). Valid while rng lives."""
    c = rng.bit_generator.ctypes
    fns = [
        ctypes.cast(f, ctypes.c_void_p).value for f in (c.next_uint64, c.next_uint32, c.next_double)
    ]
    return np.array([c.state_address, c.state.value, *fns, c.bit_generator.value], dtype=np.int64)
