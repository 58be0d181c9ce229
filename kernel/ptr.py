"""Raw-memory helpers for numba: read/write typed values at an address, call a C function pointer.

The kernel talks to Embree's C API through plain integer addresses so that every
compiled function can be cached on disk (``cache=True``): nothing here bakes a
process-specific pointer into machine code.
"""
from llvmlite import ir
from numba import types
from numba.core.extending import intrinsic

_I8P = ir.IntType(8).as_pointer()


def _loader(nbtype):
    @intrinsic
    def load(typingctx, addr):
        sig = nbtype(types.uint64)

        def codegen(context, builder, signature, args):
            llty = context.get_value_type(nbtype)
            ptr = builder.inttoptr(args[0], llty.as_pointer())
            return builder.load(ptr)

        return sig, codegen

    return load


def _storer(nbtype):
    @intrinsic
    def store(typingctx, addr, value):
        sig = types.void(types.uint64, nbtype)

        def codegen(context, builder, signature, args):
            llty = context.get_value_type(nbtype)
            ptr = builder.inttoptr(args[0], llty.as_pointer())
            val = context.cast(builder, args[1], signature.args[1], nbtype)
            builder.store(val, ptr)
            return context.get_dummy_value()

        return sig, codegen

    return store


load_f32 = _loader(types.float32)
load_u32 = _loader(types.uint32)
load_i64 = _loader(types.int64)
load_u64 = _loader(types.uint64)
store_f32 = _storer(types.float32)
store_u32 = _storer(types.uint32)
store_i32 = _storer(types.int32)
store_i64 = _storer(types.int64)


@intrinsic
def call_ptr3(typingctx, fn, a, b, c):
    """Call ``void fn(void*, void*, void*)`` given as an integer address."""
    sig = types.void(types.uint64, types.uint64, types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.VoidType(), [_I8P, _I8P, _I8P])
        fptr = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(fptr, [builder.inttoptr(x, _I8P) for x in args[1:]])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def prefetch(typingctx, addr):
    """Hint the processor to bring the cache line at address ``addr`` closer for writing (``llvm.prefetch``;
    no effect on results)."""
    sig = types.void(types.uint64)

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [_I8P, i32, i32, i32])
        fn = builder.module.globals.get("llvm.prefetch.p0")
        if fn is None:
            fn = ir.Function(builder.module, fnty, name="llvm.prefetch.p0")
        builder.call(fn, [builder.inttoptr(args[0], _I8P), i32(1), i32(3), i32(1)])
        return context.get_dummy_value()

    return sig, codegen
