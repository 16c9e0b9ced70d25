"""Explicit 16-lane int16 vectors for the SGM path update (LLVM IR through numba).

Written as plain numba loops, the update of four paths at one pixel is vectorised by
LLVM, which cannot prove that the path buffers, the cost row and the sum row do not
overlap: before every pixel's loop over the disparities it checks some 30 address
ranges at run time and spills its registers, about 70 ns a pixel — a third of the
aggregation on a 128-disparity volume (bench/stereo_roofline.md).  :func:`paths_row`
states the vectors itself (<16 x i16>, as SSE2/AVX2 ``pminsw``/``paddw`` code), so there
is no alias check to make, and runs the loop over a row's pixels too, so the per-pixel
offsets are increments and the horizontal path's minimum stays in a register; the
arithmetic is eq. 13 of Hirschmüller (2008) as in ``aggregate._four_paths``, bit for
bit (int16 path costs, uint16 sums that wrap).
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


def _reduce_min(builder, vector):
    """Smallest lane of a <16 x i16> vector of path costs, as int16.

    Path costs lie in 0 .. 32767 (L_r ≥ C ≥ 0 by eq. 13, at most C_max + P2 ≤
    ``aggregate.SENTINEL``; the running minima start at 32767), where the unsigned
    order is the signed one: ``llvm.vector.reduce.umin``, which x86 lowers to one
    ``pminuw`` of the two 8-lane halves and SSE4.1's ``phminposuw`` instead of a
    shuffle tree of four shuffles and four minima.
    """
    reduce = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_I16, [_VEC]),
                                            "llvm.vector.reduce.umin.v16i16")
    return builder.call(reduce, [vector])


def _make_paths_row(first_group: bool):
    @intrinsic
    def paths_row(typingctx, buf, mins, cost, out, penalty, cur, prev, prev_mins, pens,
                  steps, row0, n_pixels, p1):
        """Eq. 13 for four paths along one row of ``n_pixels`` pixels, all disparities.

        ``buf`` (int16, C order) holds the path costs L_r with one int16 per disparity
        d = 1 .. D of a padded axis, ``mins`` (int16) their minima over d, ``cost`` and
        ``out`` (uint16, C order) the row's window costs C and path sums, D per pixel,
        ``penalty`` (int64) P2 per direction and pixel.  For the row's first pixel (in
        sweep order): ``cur`` = (offset in ``buf`` of L_r(p, 1), offset in ``mins``) of
        the group's first direction; ``prev``, ``prev_mins`` and ``pens`` (4 int64 each)
        the offsets of each direction's L_r(p − r, 1), min_k L_r(p − r, k) and P2;
        ``row0`` that of C(p, ·) and the sum.  ``steps`` = (buf, mins, row, penalty
        offset from one pixel to the next; buf, mins offset from one direction to the
        next).  The new L_r and their minima are written at ``cur``; their sum over the
        four paths is written to ``out`` (``paths_row``) or added to it
        (``paths_row_add``).  D ≥ 16: D mod 16 disparities are a last vector overlapping
        the one before (same values stored twice, the sum added once).  In
        ``paths_row`` (the first group) the first direction is the horizontal one, whose
        predecessor is the previous pixel: its minimum is passed on in a register.

        A pixel's vectors are updated in the order its pixels lie in memory: from the
        first disparity up when the row is walked left to right (the down sweep), from
        the last one down when it is walked right to left (the up sweep).  Ascending
        vectors inside descending pixels defeated the hardware prefetchers, which follow
        one direction: the up sweep took 1.2–2.3× the down sweep's CPU time on the same
        rows (4096 × 400 × 96 census, loaded 2-core VM), and the two sweep threads of a
        strip waited on it (untiled 4096² × 96: 1.55–1.64 cores at best in the match
        phase, 1.89–1.96 after).  The updates of different disparities are independent
        and the sums wrap modulo 2¹⁶, so the order changes no bit.
        """
        sig = types.none(buf, mins, cost, out, penalty, cur, prev, prev_mins, pens, steps,
                         row0, n_pixels, p1)

        def codegen(context, builder, signature, args):
            (buf_v, mins_v, cost_v, out_v, pen_v, cur_v, prev_v, pmin_v, pens_v, steps_v,
             row0_v, n_v, p1_v) = args
            data = [context.make_array(signature.args[i])(context, builder, arg).data
                    for i, arg in enumerate((buf_v, mins_v, cost_v, out_v, pen_v))]
            buf_d, mins_d, cost_d, out_d, pen_d = data
            i64 = ir.IntType(64)
            n_disp = builder.extract_value(
                context.make_array(signature.args[2])(context, builder, cost_v).shape, 1)
            n_chunks = builder.udiv(n_disp, ir.Constant(i64, LANES))
            tail_at = builder.sub(n_disp, ir.Constant(i64, LANES))
            rest = builder.sub(n_disp, builder.mul(n_chunks, ir.Constant(i64, LANES)))
            # lanes of the overlapping last vector not yet summed: lane ≥ 16 − rest
            lane_ids = ir.Constant(_VEC, list(range(LANES)))
            fresh = builder.icmp_signed(">=", lane_ids, _splat(builder, builder.sub(
                ir.Constant(i64, LANES), rest)))
            zero = ir.Constant(_VEC, [0] * LANES)
            def ext(value, k):
                return builder.extract_value(value, k)

            cur_b, cur_m = ext(cur_v, 0), ext(cur_v, 1)
            prevs = [ext(prev_v, t) for t in range(4)]
            pmins = [ext(pmin_v, t) for t in range(4)]
            pens = [ext(pens_v, t) for t in range(4)]
            st_b, st_m, st_r, st_p, dir_b, dir_m = (ext(steps_v, k) for k in range(6))
            p1s = _splat(builder, p1_v)
            minima = [cgutils.alloca_once(builder, _VEC) for _ in range(4)]
            carried = cgutils.alloca_once_value(builder, builder.load(
                builder.gep(mins_d, [pmins[0]])))
            one = ir.Constant(i64, 1)
            descending = builder.icmp_signed("<", st_r, ir.Constant(i64, 0))
            has_tail = builder.icmp_signed(">", rest, ir.Constant(i64, 0))

            def chunk(px, at, last):
                """Update the four paths at disparity offset ``at`` of pixel ``px``."""
                c = builder.load(_vector_at(builder, cost_d, builder.add(px["row"], at)),
                                 align=2)
                total = None
                for t in range(4):
                    pos = builder.add(px["prev"][t], at)
                    centre = builder.load(_vector_at(builder, buf_d, pos), align=2)
                    below = builder.load(_vector_at(builder, buf_d, builder.sub(pos, one)),
                                         align=2)
                    over = builder.load(_vector_at(builder, buf_d, builder.add(pos, one)),
                                        align=2)
                    best = _smin(builder, centre, builder.add(_smin(builder, below, over), p1s))
                    best = _smin(builder, best, px["above"][t])
                    value = builder.add(c, builder.sub(best, px["low"][t]))
                    builder.store(value, _vector_at(builder, buf_d,
                                                    builder.add(px["cur"][t], at)), align=2)
                    builder.store(_smin(builder, builder.load(minima[t]), value), minima[t])
                    total = value if total is None else builder.add(total, value)
                target = _vector_at(builder, out_d, builder.add(px["row"], at))
                if not first_group:
                    if last:
                        total = builder.select(fresh, total, zero)
                    total = builder.add(builder.load(target, align=2), total)
                builder.store(total, target, align=2)

            with cgutils.for_range(builder, n_v) as pixels:
                i = pixels.index
                px = {"row": builder.add(row0_v, builder.mul(i, st_r)),
                      "cur": [], "prev": [], "above": [], "low": []}
                here = builder.add(cur_b, builder.mul(i, st_b))
                for t in range(4):
                    px["cur"].append(builder.add(here, builder.mul(ir.Constant(i64, t), dir_b)))
                    px["prev"].append(builder.add(prevs[t], builder.mul(i, st_b)))
                    if first_group and t == 0:
                        low = builder.load(carried)
                    else:
                        low = builder.load(builder.gep(
                            mins_d, [builder.add(pmins[t], builder.mul(i, st_m))]))
                    pen = builder.load(builder.gep(pen_d, [builder.add(pens[t],
                                                                       builder.mul(i, st_p))]))
                    px["above"].append(_splat(builder, builder.add(builder.sext(low, i64), pen)))
                    px["low"].append(_splat(builder, low))
                    builder.store(_splat(builder, ir.Constant(_I16, 32767)), minima[t])
                # a pixel's vectors in the order of its pixels in memory: ascending when
                # the row is walked left to right, descending right to left
                with builder.if_then(builder.and_(descending, has_tail)):
                    chunk(px, tail_at, True)
                with cgutils.for_range(builder, n_chunks) as loop:
                    index = builder.select(descending, builder.sub(
                        builder.sub(n_chunks, one), loop.index), loop.index)
                    chunk(px, builder.mul(index, ir.Constant(i64, LANES)), False)
                with builder.if_then(builder.and_(builder.not_(descending), has_tail)):
                    chunk(px, tail_at, True)
                here_m = builder.add(cur_m, builder.mul(i, st_m))
                for t in range(4):
                    low = _reduce_min(builder, builder.load(minima[t]))
                    at = builder.add(here_m, builder.mul(ir.Constant(i64, t), dir_m))
                    builder.store(low, builder.gep(mins_d, [at]))
                    if first_group and t == 0:
                        builder.store(low, carried)
            return context.get_dummy_value()

        return sig, codegen

    return paths_row


paths_row = _make_paths_row(True)
paths_row_add = _make_paths_row(False)


@intrinsic
def right_minima(typingctx, srow, right_key, min_disparity):
    """min over left pixels x of the key S(x, k)·2¹⁶ + k at right pixel x − d_k, one row.

    ``srow`` (W, D) uint16, C order, is the row's aggregated cost, d_k = ``min_disparity``
    + k; ``right_key`` (W) uint32 is lowered in place to each right pixel's least key
    (the caller fills it with 0xFFFFFFFF).  The loop of
    :func:`demtool.sgm.disparity._right_disparities` in <8 x i32> vectors: numba types
    the key's arithmetic as 64-bit integers, and LLVM vectorised it in 64-bit lanes (some
    600 instructions a pixel at 128 disparities against about 110 here).
    """
    if not (isinstance(srow, types.Array) and srow.layout == "C" and srow.ndim == 2
            and isinstance(min_disparity, types.Integer)):
        return None
    sig = types.none(srow, right_key, types.int64)
    i32, i64 = _I32, ir.IntType(64)
    vec32 = ir.VectorType(i32, 8)

    def codegen(context, builder, signature, args):
        s_arr = context.make_array(signature.args[0])(context, builder, args[0])
        k_arr = context.make_array(signature.args[1])(context, builder, args[1])
        s_data, k_data = s_arr.data, k_arr.data
        width = builder.extract_value(s_arr.shape, 0)
        n_disp = builder.extract_value(s_arr.shape, 1)
        min_d = args[2]
        zero64, one64, eight = (ir.Constant(i64, v) for v in (0, 1, 8))

        def clamp(value, low, high):
            value = builder.select(builder.icmp_signed("<", value, low), low, value)
            return builder.select(builder.icmp_signed(">", value, high), high, value)

        def umin(a, b):
            return builder.select(builder.icmp_unsigned("<", a, b), a, b)

        iota = ir.Constant(vec32, list(range(8)))
        reverse = ir.Constant(ir.VectorType(i32, 8), list(range(7, -1, -1)))
        sixteen = ir.Constant(vec32, [16] * 8)
        with cgutils.for_range(builder, width) as pixels:
            x = pixels.index
            base = builder.sub(x, min_d)
            k_hi = clamp(builder.add(base, one64), zero64, n_disp)
            k_lo = clamp(builder.add(builder.sub(base, width), one64), zero64, k_hi)
            start = builder.sub(base, k_lo)
            count = builder.sub(k_hi, k_lo)
            row = builder.add(builder.mul(x, n_disp), k_lo)
            n_vec = builder.udiv(count, eight)
            with cgutils.for_range(builder, n_vec) as chunks:
                i = builder.mul(chunks.index, eight)
                cost = builder.load(builder.bitcast(builder.gep(s_data, [builder.add(row, i)]),
                                                    ir.VectorType(_I16, 8).as_pointer()), align=2)
                k0 = builder.trunc(builder.add(k_lo, i), i32)
                first = builder.insert_element(ir.Constant(vec32, None), k0, ir.Constant(i32, 0))
                ks = builder.add(builder.shuffle_vector(first, ir.Constant(vec32, None),
                                                        ir.Constant(vec32, [0] * 8)), iota)
                key = builder.or_(builder.shl(builder.zext(cost, vec32), sixteen), ks)
                # right pixels start − i − 7 .. start − i: the keys in reverse order
                target = builder.bitcast(builder.gep(k_data, [builder.sub(
                    builder.sub(start, i), ir.Constant(i64, 7))]), vec32.as_pointer())
                key = builder.shuffle_vector(key, ir.Constant(vec32, None), reverse)
                builder.store(umin(builder.load(target, align=4), key), target, align=4)
            with cgutils.for_range_slice(builder, builder.mul(n_vec, eight), count,
                                          one64) as (i, _):
                cost = builder.load(builder.gep(s_data, [builder.add(row, i)]))
                key = builder.or_(builder.shl(builder.zext(cost, i32), ir.Constant(i32, 16)),
                                  builder.trunc(builder.add(k_lo, i), i32))
                target = builder.gep(k_data, [builder.sub(start, i)])
                builder.store(umin(builder.load(target), key), target)
        return context.get_dummy_value()

    return sig, codegen


def _umin(builder, a, b):
    return builder.select(builder.icmp_unsigned("<", a, b), a, b)


@intrinsic
def best_two(typingctx, srow, x):
    """Winner-takes-all at pixel ``x`` of an S row: (k, S(x, k), second), int64.

    ``srow`` (W, D ≥ 16) uint16, C order.  k is the smallest index of the least cost;
    second the least cost at least two disparities from k (65535 if there is none).
    Two passes of <16 x i16> vectors: per lane the running minimum and the index where
    it was first met, then the minimum with k − 1 .. k + 1 masked out; D mod 16 is a
    last vector overlapping the one before (a minimum and its first index do not change
    when elements are seen twice).
    """
    if not (isinstance(srow, types.Array) and srow.layout == "C" and srow.ndim == 2
            and isinstance(x, types.Integer)):
        return None
    ret = types.UniTuple(types.int64, 3)
    sig = ret(srow, types.int64)
    i64 = ir.IntType(64)

    def codegen(context, builder, signature, args):
        s_arr = context.make_array(signature.args[0])(context, builder, args[0])
        n_disp = builder.extract_value(s_arr.shape, 1)
        row = builder.mul(args[1], n_disp)
        n_chunks = builder.udiv(n_disp, ir.Constant(i64, LANES))
        last = builder.sub(n_disp, ir.Constant(i64, LANES))
        iota = ir.Constant(_VEC, list(range(LANES)))
        ones = _splat(builder, ir.Constant(_I16, 0xFFFF))

        def load(at):
            return builder.load(_vector_at(builder, s_arr.data, builder.add(row, at)), align=2)

        def each_vector(step):
            """step(offset) for offsets 0, 16, .. and D − 16 (the overlapping last one)."""
            with cgutils.for_range(builder, n_chunks) as loop:
                step(builder.mul(loop.index, ir.Constant(i64, LANES)))
            with builder.if_then(builder.icmp_signed(">", builder.srem(
                    n_disp, ir.Constant(i64, LANES)), ir.Constant(i64, 0))):
                step(last)

        # a lane that never goes below 65535 has it first at its first element
        low_v = cgutils.alloca_once_value(builder, ones)
        first_v = cgutils.alloca_once_value(builder, iota)

        def first_pass(at):
            values, low = load(at), builder.load(low_v)
            lower = builder.icmp_unsigned("<", values, low)
            builder.store(builder.select(lower, values, low), low_v)
            index = builder.add(iota, _splat(builder, at))
            builder.store(builder.select(lower, index, builder.load(first_v)), first_v)

        each_vector(first_pass)
        low_vec = builder.load(low_v)
        low = _reduce_min(builder, low_vec)
        at_low = builder.icmp_unsigned("==", low_vec, _splat(builder, low))
        best = _reduce_min(builder, builder.select(at_low, builder.load(first_v), ones))
        second_v = cgutils.alloca_once_value(builder, ones)
        # lanes k with k − best + 1 ≤ 2 (unsigned): best − 1 .. best + 1
        shift = _splat(builder, builder.sub(ir.Constant(_I16, 1), best))
        two = _splat(builder, ir.Constant(_I16, 2))

        def second_pass(at):
            index = builder.add(builder.add(iota, _splat(builder, at)), shift)
            near = builder.sext(builder.icmp_unsigned("<=", index, two), _VEC)
            values = builder.or_(load(at), near)
            builder.store(_umin(builder, builder.load(second_v), values), second_v)

        each_vector(second_pass)
        second = _reduce_min(builder, builder.load(second_v))
        return context.make_tuple(builder, ret, [builder.zext(v, i64)
                                                 for v in (best, low, second)])

    return sig, codegen
