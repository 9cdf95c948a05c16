"""The GPU backend's sort: a stable least-significant-digit radix sort of 64-bit records by
their upper 32 bits (a cell), in a fixed number of launches (numba.cuda).

A record is ``(cell << 32) | slot``. ``digits`` counts every pass's digits of all records
at once; each ``scatter`` launch is one pass: a block ranks its tile stably in shared
memory, half a digit at a time, learns from the tiles before it where its digits go
(decoupled look-back: no extra launch) and writes out. Input in id order and stable passes
make the result sorted by (cell, id), a pure function of the state, in ``O(N)`` work
however many particles share a cell. :func:`radix` runs the passes; the step's ``finish``
kernel (:mod:`flocking.backends.cuda_kernels`) readies the counters for the next sort.
"""

from __future__ import annotations

import functools
import types
import typing

import numpy as np
from numba import cuda

from ..rules import rebind

#: the sort record of a slot no particle fills: sorts after every real one
SENTINEL = np.uint64(0xFFFFFFFFFFFFFFFF)
#: the lower half of a record (its slot) and where its key starts
LOW = np.uint64(0xFFFFFFFF)
KEY = np.uint64(32)


class Launch(typing.NamedTuple):
    """The shape of the launches: threads per ``block`` (a power of two), radix ``bits``
    a pass (even, at most ``log2(block)`` so that each digit has a thread) and sort
    ``items`` a thread."""

    block: int
    bits: int
    items: int


def passes(key_bits: int, bits: int) -> int:
    """Radix passes over keys of ``key_bits`` bits, ``bits`` a pass (at least one).

    >>> passes(19, 8), passes(1, 8), passes(24, 4)
    (3, 1, 6)
    """
    return max(1, -(-key_bits // bits))


# The sizes of a launch: the functions below read them as globals, and build() compiles
# each with its launch's values in place of these.
BLOCK, BITS, ITEMS, DIGITS, SUB, SUBD, TILE, PMAX, HSIZE, CSIZE = 256, 8, 8, 256, 4, 16, 2048, 4, 1024, 4096
MASK, SUBMASK, CTYPE, _KEY = np.uint64(255), np.uint64(15), np.int16, KEY


def digit_of(v, shift):
    return np.int64((v >> shift) & MASK)

def block_scan(part, more, tid):
    """Inclusive prefix sums of ``part[:BLOCK]`` and ``more[:BLOCK]`` in place, side
    by side; every thread of the block calls it after writing its entries
    (Hillis-Steele: log2(BLOCK) rounds)."""
    cuda.syncthreads()
    off = 1
    while off < BLOCK:
        v, w = 0, 0
        if tid >= off:
            v, w = part[tid - off], more[tid - off]
        cuda.syncthreads()
        part[tid] += v
        more[tid] += w
        cuda.syncthreads()
        off *= 2

def digits(rec, hist, m, npass, clock, tick):
    """Count every pass's digits of ``rec[:m]`` into ``hist[p * DIGITS + digit]``
    (zero on entry); with ``tick``, the step counter moves on (the step kernel,
    which reads it, is done)."""
    h = cuda.shared.array(HSIZE, np.int32)
    tid = cuda.threadIdx.x
    if tick and cuda.blockIdx.x == 0 and tid == 0:
        clock[0] += 1
    for e in range(tid, HSIZE, BLOCK):
        h[e] = 0
    cuda.syncthreads()
    first = cuda.blockIdx.x * TILE
    for q in range(ITEMS):
        g = first + q * BLOCK + tid
        if g < m:
            v = rec[g]
            for p in range(npass):
                cuda.atomic.add(h, p * DIGITS + digit_of(v, _KEY + np.uint64(p * BITS)), 1)
    cuda.syncthreads()
    for e in range(tid, npass * DIGITS, BLOCK):
        if h[e] != 0:
            cuda.atomic.add(hist, e, h[e])


def tiles_before(status, tile, d, tag, mine):
    """Items of digit ``d`` in the tiles before ``tile`` (decoupled look-back), once the
    tile has published its own ``mine`` and then its inclusive prefix in ``status``.
    A status word is ``tag << 33 | inclusive << 32 | count``, the tag (the sort and the
    pass, never 0) telling this pass's words from older ones."""
    slot = tile * DIGITS + d
    before = np.int64(0)
    if tile == 0:
        cuda.atomic.exch(status, slot, (tag << 33) | (np.int64(1) << 32) | mine)
        return before
    cuda.atomic.exch(status, slot, (tag << 33) | mine)
    j = tile - 1
    while j >= 0:
        w = cuda.atomic.add(status, j * DIGITS + d, 0)
        if (w >> 33) != tag:
            continue  # tile j has not published yet
        before += w & 0xFFFFFFFF
        if (w >> 32) & 1:
            break
        j -= 1
    cuda.atomic.exch(status, slot, (tag << 33) | (np.int64(1) << 32) | (before + mine))
    return before


def scatter(src, dst, m, p, hist, status, tiles, clock):
    """Pass ``p`` of the radix sort, ``src[:m]`` into ``dst``: stable by the digit.

    Tiles are handed out in launch order by ``tiles[p]``. A block loads its tile and
    sorts it stably by the digit in shared memory, half a digit at a time: each thread
    counts its own run of items into its column of ``cnt``, a prefix sum over
    (sub-digit, thread) gives every item its place. It then learns, per digit, how
    many items the tiles before it hold (decoupled look-back: each tile publishes its
    count, then its inclusive prefix, in ``status``, tagged with the sort and pass so
    that nothing needs clearing) and writes each digit's run to ``digit start + items
    of earlier tiles + rank in the tile``."""
    keys = cuda.shared.array(TILE, np.uint64)
    other = cuda.shared.array(TILE, np.uint64)
    cnt = cuda.shared.array(CSIZE, CTYPE)
    part = cuda.shared.array(BLOCK, np.int32)
    more = cuda.shared.array(BLOCK, np.int32)
    tcount = cuda.shared.array(DIGITS, np.int32)
    tstart = cuda.shared.array(DIGITS, np.int32)
    base = cuda.shared.array(DIGITS, np.int64)
    tile_of = cuda.shared.array(1, np.int64)
    tid = cuda.threadIdx.x
    if tid == 0:
        tile_of[0] = cuda.atomic.add(tiles, p, 1)
    if tid < DIGITS:
        tcount[tid] = 0
    for e in range(SUBD):
        cnt[e * BLOCK + tid] = 0
    cuda.syncthreads()
    tile = tile_of[0]
    shift = _KEY + np.uint64(p * BITS)
    first = tile * TILE
    for q in range(ITEMS):
        g = first + q * BLOCK + tid
        v = SENTINEL
        if g < m:
            v = src[g]
            cuda.atomic.add(tcount, digit_of(v, shift), 1)
        keys[q * BLOCK + tid] = v
    cuda.syncthreads()
    # stable sort of the tile by the digit, one half at a time (keys -> other -> keys)
    for sp in range(2):
        a, b = (keys, other) if sp % 2 == 0 else (other, keys)
        sub = shift + np.uint64(sp * SUB)
        for q in range(ITEMS):
            e = np.int64((a[tid * ITEMS + q] >> sub) & SUBMASK) * BLOCK + tid
            cnt[e] += 1
        cuda.syncthreads()
        # exclusive prefix sum of cnt (sub-digit major): each thread a run of SUBD
        total = 0
        for e in range(SUBD):
            total += cnt[tid * SUBD + e]
        part[tid] = total
        more[tid] = 0
        block_scan(part, more, tid)
        acc = part[tid] - total
        for e in range(SUBD):
            v = cnt[tid * SUBD + e]
            cnt[tid * SUBD + e] = acc
            acc += v
        cuda.syncthreads()
        for q in range(ITEMS):  # from here on a thread touches its own column only
            v = a[tid * ITEMS + q]
            e = np.int64((v >> sub) & SUBMASK) * BLOCK + tid
            at = cnt[e]
            cnt[e] = at + 1
            b[at] = v
        for e in range(SUBD):
            cnt[e * BLOCK + tid] = 0
        cuda.syncthreads()
    # where each digit starts in the tile, and in the whole output
    part[tid] = tcount[tid] if tid < DIGITS else 0
    more[tid] = hist[p * DIGITS + tid] if tid < DIGITS else 0
    block_scan(part, more, tid)
    if tid < DIGITS:
        mine = np.int64(tcount[tid])
        tstart[tid] = part[tid] - mine
        tag = np.int64(1 + (clock[1] * PMAX + p) % (2**30 - 1))
        before = tiles_before(status, tile, tid, tag, mine)
        base[tid] = np.int64(more[tid]) - hist[p * DIGITS + tid] + before
    cuda.syncthreads()
    for q in range(ITEMS):
        at = q * BLOCK + tid
        v = keys[at]
        d = digit_of(v, shift)
        rank = at - tstart[d]
        if rank < tcount[d]:
            dst[base[d] + rank] = v


@functools.lru_cache(maxsize=None)
def build(launch: Launch) -> types.SimpleNamespace:
    """The sort's kernels and sizes for ``launch``: the functions below compiled from their
    text with this launch's sizes as their globals."""
    BLOCK, BITS, ITEMS = launch
    DIGITS = 1 << BITS
    if DIGITS > BLOCK:
        raise ValueError("cuda_sort.build: 2**bits must not exceed block")
    if BITS % 2:
        raise ValueError("cuda_sort.build: bits must be even")
    # a tile is ranked in two halves of the digit (keys -> other -> keys), with a counter
    # per (half-digit, thread): 16 x BLOCK for 8-bit digits
    SUB = BITS // 2
    SUBD = 1 << SUB
    TILE = BLOCK * ITEMS
    PMAX = passes(31, BITS)
    HSIZE, CSIZE = PMAX * DIGITS, SUBD * BLOCK  # shared array sizes must be constants
    MASK = np.uint64(DIGITS - 1)
    SUBMASK = np.uint64(SUBD - 1)
    # sub-digit counters: a tile holds at most 32767 items, so int16 counts suffice
    CTYPE = np.int16 if TILE < 2**15 else np.int32
    _KEY = KEY
    namespace = {**globals(), "BLOCK": BLOCK, "BITS": BITS, "ITEMS": ITEMS, "DIGITS": DIGITS, "SUB": SUB,
                 "SUBD": SUBD, "TILE": TILE, "PMAX": PMAX, "HSIZE": HSIZE, "CSIZE": CSIZE, "MASK": MASK,
                 "SUBMASK": SUBMASK, "CTYPE": CTYPE, "_KEY": _KEY}
    for name in ("digit_of", "block_scan", "tiles_before"):
        namespace[name] = cuda.jit(device=True)(rebind(globals()[name], namespace))
    for name in ("digits", "scatter"):
        namespace[name] = cuda.jit(rebind(globals()[name], namespace))
    digits, scatter, block_scan = namespace["digits"], namespace["scatter"], namespace["block_scan"]

    return types.SimpleNamespace(digits=digits, scatter=scatter, block_scan=block_scan, bits=BITS,
                                 digits_per_pass=DIGITS, tile=TILE, block=BLOCK, max_passes=PMAX, hist_size=HSIZE)


def radix_launches(k, rec, rec2, m: int, npass: int, hist, status, tiles, clock, tick: bool, stream=0):
    """The launches that sort ``rec[:m]`` by the upper 32 bits (``npass`` passes of the
    sort ``k`` from :func:`build`, ``rec2`` the other buffer), in order, each as ``(name,
    a function that makes it)``, and the buffer that will hold the result. With ``tick``,
    ``digits`` moves the step counter ``clock[0]`` on."""
    grid = -(-m // k.tile)
    out = [("digits", lambda: k.digits[grid, k.block, stream](rec, hist, m, npass, clock, tick))]
    bufs = (rec, rec2)
    for p in range(npass):
        src, dst = bufs[p % 2], bufs[(p + 1) % 2]
        out.append((f"scatter{p}", lambda src=src, dst=dst, p=p: k.scatter[grid, k.block, stream](
            src, dst, m, p, hist, status, tiles, clock)))
    return out, bufs[npass % 2]


def radix(k, rec, rec2, m: int, npass: int, hist, status, tiles, clock, tick: bool, stream=0):
    """Sort ``rec[:m]`` as :func:`radix_launches` says; the buffer that holds the result."""
    launches, result = radix_launches(k, rec, rec2, m, npass, hist, status, tiles, clock, tick, stream)
    for _, launch in launches:
        launch()
    return result
