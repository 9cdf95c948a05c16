"""LLVM intrinsics for the CPU kernels: an atomic counter, a prefetch, a 4-bit mask and a
compress, each written as numba ``@intrinsic`` IR.

Each is machine code numba's own lowering does not produce. Where the best form depends on
the instruction set (the compress), it is chosen for the *target* numba compiles for, not
the machine this runs on: they differ when ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` make
a cache portable (``NUMBA_CPU_NAME=generic``), and an instruction the target lacks aborts
LLVM, killing the process. :func:`target_features` reads the target as numba does.

>>> compress_form("+avx2,-avx512f", (22, 1, 0)), compress_form("", (22, 1, 0))
('avx2', 'select')
"""

from __future__ import annotations

import numba.core.config
from llvmlite import ir
from llvmlite.binding import llvm_version_info
from numba.core import cgutils, types
from numba.core.codegen import get_host_cpu_features
from numba.extending import intrinsic

I8P = ir.IntType(8).as_pointer()
I32, I64 = ir.IntType(32), ir.IntType(64)


def target_features() -> str:
    """The features (LLVM's string, ``+avx2,-avx512f,...``) of the machine numba compiles
    for: ``NUMBA_CPU_FEATURES`` when set (``NUMBA_CPU_NAME=generic`` sets it to ``""``, the
    baseline of the architecture), else the host's, exactly as numba's CPU codegen does.

    Only features named here count: a form that needs one is chosen only when the target
    enables it by name, so a CPU name's implied features never make a wrong choice (at
    worst a slower one).
    """
    features = numba.core.config.CPU_FEATURES
    return get_host_cpu_features() if features is None else features


def enabled(features: str) -> set[str]:
    """The features that ``features`` (LLVM's string) switches on.

    >>> sorted(enabled("+avx2,-avx512f,+fma"))
    ['avx2', 'fma']
    """
    return {f[1:] for f in features.split(",") if f.startswith("+")}


@intrinsic
def fetch_add(typingctx, counter):
    """Atomically ``counter[0] += 1``, returning the old value: hands out work blocks."""
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, signature.args[0], ary, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return sig, codegen


#: ``llvm.prefetch`` mangled for the pointers llvmlite writes (typed ``i8*`` before LLVM's
#: opaque pointers, ``ptr`` after)
PREFETCH = "llvm.prefetch.p0i8" if str(I8P) == "i8*" else "llvm.prefetch.p0"


@intrinsic
def prefetch(typingctx, ring, slot, pid):
    """Hint the cache to fetch ``ring[slot, pid]`` for writing (``llvm.prefetch``)."""
    sig = types.void(ring, slot, pid)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        idx = [context.cast(builder, args[1], signature.args[1], types.intp),
               context.cast(builder, args[2], signature.args[2], types.intp), context.get_constant(types.intp, 0)]
        ptr = cgutils.get_item_pointer(context, builder, signature.args[0], ary, idx)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [I8P, I32, I32, I32]),
                                            PREFETCH)
        builder.call(fn, [builder.bitcast(ptr, I8P), I32(1), I32(3), I32(1)])
        return context.get_dummy_value()

    return sig, codegen


def mask_bits(builder, bits):
    """The four booleans ``bits`` as one ``<4 x i1>`` vector."""
    mask = ir.Constant(ir.VectorType(ir.IntType(1), 4), None)
    for lane, bit in enumerate(bits):
        mask = builder.insert_element(mask, bit, I32(lane))
    return mask


@intrinsic
def mask4(typingctx, b0, b1, b2, b3):
    """``b0 + 2 b1 + 4 b2 + 8 b3`` (uint64) from four booleans, built as the bits of one
    vector of four so that LLVM takes it from a vector comparison in one move."""
    sig = types.uint64(types.boolean, types.boolean, types.boolean, types.boolean)

    def codegen(context, builder, signature, args):
        return builder.zext(builder.bitcast(mask_bits(builder, args), ir.IntType(4)), I64)

    return sig, codegen


#: the forms of :func:`compress_ir`'s machine code: LLVM's own compress (one
#: ``vpcompressq``, x86 with AVX-512 and LLVM 19 on), a permutation by ``vpermd`` (x86 with
#: AVX2) and selects (any target). With AVX-512, the compress ran cohesion 1.5 % faster than
#: ``vpermd`` on an Intel Rocket Lake and 15 % faster on an AMD Zen 4 (2D, N = 1e5); without
#: AVX-512 LLVM expands it through memory, so it is chosen only where the target has it.
COMPRESS_FORMS = ("avx512", "avx2", "select")


def compress_form(features: str, llvm: tuple = llvm_version_info) -> str:
    """The form of :func:`compress_ir` for a target with ``features`` (LLVM's string) and
    LLVM version ``llvm``: ``avx512`` where the target enables AVX-512 F and VL by name
    and LLVM has its compress (19 on), ``avx2`` where it enables AVX2, else ``select``.

    >>> compress_form("+avx2,+avx512f,+avx512vl", (22, 1, 0)), compress_form("+avx2,+avx512f,+avx512vl", (14, 0, 6))
    ('avx512', 'avx2')
    >>> compress_form("-avx2,+sse4.2"), compress_form("+neon")
    ('select', 'select')
    """
    on = enabled(features)
    if llvm >= (19,) and {"avx512f", "avx512vl"} <= on:
        return "avx512"
    return "avx2" if "avx2" in on else "select"


def table(builder, name, vt, rows):
    """A constant global array of vectors of type ``vt`` in the module of ``builder``,
    made once per module."""
    found = builder.module.globals.get(name)
    if found is None:
        tt = ir.ArrayType(vt, len(rows))
        found = ir.GlobalVariable(builder.module, tt, name)
        found.initializer = ir.Constant(tt, [ir.Constant(vt, row) for row in rows])
        found.global_constant = True
        found.linkage = "internal"
    return found


def compress_ir(builder, values, bits, form):
    """LLVM IR for :data:`compress4`: the four doubles ``values`` whose ``bits`` are set,
    moved to the front in order, then zeros, in one of :data:`COMPRESS_FORMS`. All work
    on 64-bit integers (the bits of the doubles, moved unchanged; LLVM 22 cannot expand a
    compress of doubles without AVX-512)."""
    vt = ir.VectorType(I64, 4)
    vec = ir.Constant(vt, None)
    for lane in range(4):
        vec = builder.insert_element(vec, builder.bitcast(values[lane], I64), I32(lane))
    if form == "avx512":
        mt = ir.VectorType(ir.IntType(1), 4)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vt, [vt, mt, vt]),
                                            "llvm.experimental.vector.compress.v4i64")
        out = builder.call(fn, [vec, mask_bits(builder, bits), ir.Constant(vt, [0] * 4)])
        return [builder.bitcast(builder.extract_element(out, I32(lane)), ir.DoubleType()) for lane in range(4)]
    # by the 4-bit mask, a table row: the source lane of each lane of the result, and all
    # ones where a lane holds a value (zeros after the last)
    counts = [bin(m).count("1") for m in range(16)]
    rows = [[lane for lane in range(4) if m >> lane & 1] + [0] * (4 - counts[m]) for m in range(16)]
    keep = table(builder, "flocking_compress_keep", vt, [[-1] * c + [0] * (4 - c) for c in counts])
    m = builder.zext(builder.bitcast(mask_bits(builder, bits), ir.IntType(4)), I64)
    if form == "avx2":  # vpermd: the 32-bit halves of each source lane
        v8 = ir.VectorType(I32, 8)
        halves = [[h for lane in r for h in (2 * lane, 2 * lane + 1)] for r in rows]
        source = builder.load(builder.gep(table(builder, "flocking_compress_halves", v8, halves), [I64(0), m]))
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(v8, [v8, v8]), "llvm.x86.avx2.permd")
        out = builder.bitcast(builder.call(fn, [builder.bitcast(vec, v8), source]), vt)
    elif form == "select":
        source = builder.load(builder.gep(table(builder, "flocking_compress_lanes", vt, rows), [I64(0), m]))
        out = ir.Constant(vt, [0] * 4)
        for lane in range(4):
            at = ir.Constant(ir.VectorType(I32, 4), [lane] * 4)
            spread = builder.shuffle_vector(vec, ir.Constant(vt, None), at)
            out = builder.select(builder.icmp_unsigned("==", source, ir.Constant(vt, [lane] * 4)), spread, out)
    else:
        raise ValueError(f"form: must be one of {COMPRESS_FORMS} (got {form!r})")
    out = builder.and_(out, builder.load(builder.gep(keep, [I64(0), m])))
    return [builder.bitcast(builder.extract_element(out, I32(lane)), ir.DoubleType()) for lane in range(4)]


def compress_intrinsic(form: str):
    """:data:`compress4` in one of :data:`COMPRESS_FORMS` (the tests build each)."""
    if form not in COMPRESS_FORMS:
        raise ValueError(f"form: must be one of {COMPRESS_FORMS} (got {form!r})")

    @intrinsic
    def compress(typingctx, v0, v1, v2, v3, b0, b1, b2, b3):
        sig = types.UniTuple(types.float64, 4)(*[types.float64] * 4, *[types.boolean] * 4)

        def codegen(context, builder, signature, args):
            return context.make_tuple(builder, signature.return_type, compress_ir(builder, args[:4], args[4:], form))

        return sig, codegen

    return compress


#: the form of :data:`compress4` for the machine numba compiles for
COMPRESS = compress_form(target_features())

#: ``compress4(v0, v1, v2, v3, b0, b1, b2, b3)``: those of the four doubles ``v`` whose
#: ``b`` is true, in order, then zeros (a tuple of four), for numba-compiled code, in the
#: form :data:`COMPRESS`. It writes cohesion's noted displacements a group of four at a
#: time: :func:`flocking.backends.cpu_kernels.note`.
compress4 = compress_intrinsic(COMPRESS)
