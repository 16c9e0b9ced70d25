"""Explicit 16-lane int16 vectors for the SGM path update (LLVM IR through numba).

Written as plain numba loops, the update of four paths at one pixel
(:func:`demtool.sgm.aggregate._four_paths`) is vectorised by LLVM, which cannot prove
that the path buffers, the cost row and the sum row do not overlap: before every
pixel's loop over the disparities it checks some 30 address ranges at run time and
spills its registers, about 70 ns a pixel — a third of the aggregation on a
128-disparity volume (bench/stereo_roofline.md).  :func:`paths_chunks` states the
vectors itself (<16 x i16>, as SSE2/AVX2 ``pminsw``/``paddw`` code), so there is no
alias check to make; the arithmetic is eq. 13 of Hirschmüller (2008) as in
``_four_paths``, bit for bit (int16 path costs, uint16 sums that wrap).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

LANES = 16
_I16 = ir.IntType(16)
_I32 = ir.IntType(32)
_VEC = ir.VectorType(_I16, LANES)


def _splat(builder, value):
    """A vector of ``value`` (an integer, truncated to 16 bits) in every lane."""
    value = builder.trunc(value, _I16) if value.type.width > 16 else value
    first = builder.insert_element(ir.Constant(_VEC, None), value, ir.Constant(_I32, 0))
    return builder.shuffle_vector(first, ir.Constant(_VEC, None),
                                  ir.Constant(ir.VectorType(_I32, LANES), [0] * LANES))


def _vector_at(builder, base, index):
    """Pointer to the 16 int16 elements starting at element ``index`` of ``base``."""
    return builder.bitcast(builder.gep(base, [index]), _VEC.as_pointer())


def _smin(builder, a, b):
    return builder.select(builder.icmp_signed("<", a, b), a, b)


def _reduce_smin(builder, vector):
    """Smallest lane of a <16 x i16> vector (a shuffle tree), as int16."""
    for half in (8, 4, 2, 1):
        mask = [i + half if i < half else i for i in range(LANES)]
        shuffled = builder.shuffle_vector(vector, vector,
                                          ir.Constant(ir.VectorType(_I32, LANES), mask))
        vector = _smin(builder, vector, shuffled)
    return builder.extract_element(vector, ir.Constant(_I32, 0))


def _make_paths_chunks(accumulate: bool):
    @intrinsic
    def paths_chunks(typingctx, buf, cur, prev, cost, out, n_chunks, p1, above, low):
        """Eq. 13 for four paths at one pixel, disparities 16·i .. 16·i + 15, i < n_chunks.

        ``buf`` is the int16 path-cost array; ``cur`` and ``prev`` (4 int64 each) are
        the flat element offsets in it of the first disparity (k = 1 of its padded axis)
        of each path's new and previous costs L_r(p) and L_r(p − r); ``cost`` and
        ``out`` (uint16) the pixel's cost and path-sum rows as (array, flat offset);
        ``above`` (4 int64) is min_k L_r(p − r, k) + P2 of each path and ``low`` (4
        int64) min_k L_r(p − r, k).  Writes the new path costs, writes (or, in the
        accumulating variant, adds) their sum to ``out`` and returns each path's
        minimum over these disparities (4 int64).
        """
        ret = types.UniTuple(types.int64, 4)
        sig = ret(buf, cur, prev, cost, out, n_chunks, p1, above, low)

        def codegen(context, builder, signature, args):
            buf_v, cur_v, prev_v, cost_v, out_v, chunks_v, p1_v, above_v, low_v = args
            buf_data = context.make_array(signature.args[0])(context, builder, buf_v).data
            cost_arr, cost_off = (builder.extract_value(cost_v, i) for i in (0, 1))
            out_arr, out_off = (builder.extract_value(out_v, i) for i in (0, 1))
            cost_data = context.make_array(signature.args[3].types[0])(
                context, builder, cost_arr).data
            out_data = context.make_array(signature.args[4].types[0])(
                context, builder, out_arr).data
            curs = [builder.extract_value(cur_v, t) for t in range(4)]
            prevs = [builder.extract_value(prev_v, t) for t in range(4)]
            aboves = [_splat(builder, builder.extract_value(above_v, t)) for t in range(4)]
            lows = [_splat(builder, builder.extract_value(low_v, t)) for t in range(4)]
            p1s = _splat(builder, p1_v)
            minima = [cgutils.alloca_once_value(builder, _splat(builder, ir.Constant(
                _I16, 32767))) for _ in range(4)]
            one = ir.Constant(ir.IntType(64), 1)
            with cgutils.for_range(builder, chunks_v) as loop:
                step = builder.mul(loop.index, ir.Constant(ir.IntType(64), LANES))
                total = None
                c = builder.load(_vector_at(builder, cost_data, builder.add(cost_off, step)),
                                 align=2)
                for t in range(4):
                    at = builder.add(prevs[t], step)
                    centre = builder.load(_vector_at(builder, buf_data, at), align=2)
                    below = builder.load(_vector_at(builder, buf_data, builder.sub(at, one)),
                                         align=2)
                    over = builder.load(_vector_at(builder, buf_data, builder.add(at, one)),
                                        align=2)
                    best = _smin(builder, centre, builder.add(_smin(builder, below, over), p1s))
                    best = _smin(builder, best, aboves[t])
                    value = builder.add(c, builder.sub(best, lows[t]))
                    builder.store(value, _vector_at(builder, buf_data,
                                                    builder.add(curs[t], step)), align=2)
                    builder.store(_smin(builder, builder.load(minima[t]), value), minima[t])
                    total = value if total is None else builder.add(total, value)
                target = _vector_at(builder, out_data, builder.add(out_off, step))
                if accumulate:
                    total = builder.add(builder.load(target, align=2), total)
                builder.store(total, target, align=2)
            results = [builder.sext(_reduce_smin(builder, builder.load(m)), ir.IntType(64))
                       for m in minima]
            return context.make_tuple(builder, ret, results)

        return sig, codegen

    return paths_chunks


paths_chunks = _make_paths_chunks(False)
paths_chunks_add = _make_paths_chunks(True)
