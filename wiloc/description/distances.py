"""Difference kernels: one per metric, computed blockwise so no N x N matrix must fit in RAM.

``l1`` (uint8 and float32) and ``hamming`` run in one numba kernel built from explicit LLVM vector
code: rows are cut into 64-byte chunks and a 4 x 4 tile of (query, reference) row pairs is
accumulated per chunk, so each loaded chunk is used four times from registers. The per-chunk
operation is chosen when numba compiles for the CPU at hand (see docs/kernels.md):

* ``l1`` on uint8: the x86 ``psadbw`` instruction at the widest width the CPU has (AVX-512BW,
  AVX2, SSE2), or portable max - min arithmetic on other CPUs;
* ``hamming``: popcount of the XOR of uint64 words (``llvm.ctpop``, which becomes ``vpopcntq``
  where the CPU has it and a shuffle-table popcount elsewhere);
* ``l1`` on float32: |a - b| summed in 16 float32 lanes (on every CPU, so that the sums are the
  same everywhere), then the lanes added in order.

``sqeuclidean`` and ``cosine`` use a BLAS matrix product.

The kernels' threads idle between blocks while a run's other threads (the method's steps and
what it reads ahead) work, and OpenMP's default is to keep idle threads spinning: that cost a
cold ``catgraph`` run at N = 35,000 about 1.6 of its 26 CPU-s (docs/scaling.md). So unless
``OMP_WAIT_POLICY`` is set, importing this module sets it to ``PASSIVE`` (idle threads sleep),
before numba starts the kernels' threads; it has no effect where OpenMP is already running.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import llvmlite.binding as llvm_binding
import numpy as np
from llvmlite import ir
from numba import config, njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

# The one list of metric names lives in the registry; re-exported here.
from wiloc.descriptors.registry import METRICS
from wiloc.errors import ParameterError, WilocError
from wiloc.jitcache import SIMD_VARIABLE

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # read when numba first starts OpenMP (see above)

CHUNK_BYTES = 64  # rows are zero-padded to a multiple of this for the SIMD kernel
TILE = 4  # query rows x reference rows accumulated together per chunk
PANEL_ROWS = 64  # query rows per parallel work item (about 74 KB of sad rows: stays in L2)
#: The version of what the difference functions compute, which cached results of them record (a
#: map's summary, ``differences.map_summary``): 2, float metrics summed in float64 (:func:`_product`);
#: 3, float32 ``l1`` summed in 16 lanes on every CPU (a narrower CPU's summaries were its own), and a
#: product's difference below its rounding's bound 0 (:func:`_noise_floor`).
DIFFERENCES_VERSION = 3
PRODUCT_ROWS = 256  # query rows per float64 matrix product (:func:`_product`): 256 x N x 8 bytes of scratch

_I8 = ir.IntType(8)
_I64 = ir.IntType(64)
_F32 = ir.FloatType()
_F64 = ir.DoubleType()


def _cpu_features() -> frozenset[str]:
    """The CPU features numba compiles for (its override variable first, as numba does)."""
    text = config.CPU_FEATURES if config.CPU_FEATURES is not None else llvm_binding.get_host_cpu_features().flatten()
    return frozenset(f[1:] for f in text.split(",") if f.startswith("+"))


#: The kernels' instruction sets, widest first, with the CPU feature each needs.
SIMD_PATHS = {"avx512": "avx512bw", "avx2": "avx2", "sse2": "sse2", "generic": ""}


def simd_path() -> str:
    """Name of the instruction set the kernels use: avx512, avx2, sse2 or generic.

    The widest the CPU has, or the one ``$WILOC_SIMD`` names if that is narrower (never a wider
    one: the CPU could not run it).
    """
    features = _cpu_features()
    widest = next(name for name, feature in SIMD_PATHS.items() if not feature or feature in features)
    forced = os.environ.get(SIMD_VARIABLE, "")
    if not forced:
        return widest
    if forced not in SIMD_PATHS:
        raise WilocError(SIMD_VARIABLE, f"unknown instruction set {forced!r}; expected one of {', '.join(SIMD_PATHS)}")
    order = list(SIMD_PATHS)
    return order[max(order.index(forced), order.index(widest))]


simd_path()  # a bad $WILOC_SIMD is reported here, in one line, rather than from inside numba's compiler


_VECTOR_BYTES = {"avx512": 64, "avx2": 32, "sse2": 16, "generic": 16}
_PSADBW = {
    "avx512": "llvm.x86.avx512.psad.bw.512",
    "avx2": "llvm.x86.avx2.psad.bw",
    "sse2": "llvm.x86.sse2.psad.bw",
}

# A chunk operation: (builder, loaded vector a, loaded vector b) -> partial sums to accumulate.
_ChunkOp = Callable[[ir.IRBuilder, ir.Value, ir.Value], ir.Value]


def _declare(builder: ir.IRBuilder, name: str, ret: ir.Type, *args: ir.Type) -> ir.Function:
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, list(args)), name)


def _chunk_op(builder: ir.IRBuilder, dtype: types.Type, path: str) -> tuple[ir.VectorType, ir.VectorType, _ChunkOp]:
    """(load type, accumulator type, operation) for one vector of the given element type."""
    width = _VECTOR_BYTES[path]
    if dtype == types.uint8:
        load = ir.VectorType(_I8, width)
        if path in _PSADBW:
            acc = ir.VectorType(_I64, width // 8)
            psadbw = _declare(builder, _PSADBW[path], acc, load, load)
            return load, acc, lambda b, x, y: b.call(psadbw, [x, y])
        acc = ir.VectorType(_I64, width)
        umax = _declare(builder, f"llvm.umax.v{width}i8", load, load, load)
        umin = _declare(builder, f"llvm.umin.v{width}i8", load, load, load)
        return load, acc, lambda b, x, y: b.zext(b.sub(b.call(umax, [x, y]), b.call(umin, [x, y])), acc)
    if dtype == types.uint64:
        load = ir.VectorType(_I64, width // 8)
        ctpop = _declare(builder, f"llvm.ctpop.v{width // 8}i64", load, load)
        return load, load, lambda b, x, y: b.call(ctpop, [b.xor(x, y)])
    # float32: one chunk's 16 lanes whatever the vector width, so that each lane sums the same
    # values in the same order and the ordered reduction (_reduce) adds the lanes alike on every
    # CPU: a narrower width's own lanes would sum in another order (SPEC section 11)
    load = ir.VectorType(_F32, CHUNK_BYTES // 4)
    fabs = _declare(builder, f"llvm.fabs.v{load.count}f32", load, load)
    return load, load, lambda b, x, y: b.call(fabs, [b.fsub(x, y)])


def _reduce(builder: ir.IRBuilder, acc: ir.Value) -> ir.Value:
    """Sum of the lanes of an accumulator, as a double."""
    lanes = acc.type.count
    if isinstance(acc.type.element, ir.IntType):
        total = builder.call(_declare(builder, f"llvm.vector.reduce.add.v{lanes}i64", _I64, acc.type), [acc])
        return builder.uitofp(total, _F64)
    fadd = _declare(builder, f"llvm.vector.reduce.fadd.v{lanes}f32", _F32, _F32, acc.type)
    return builder.fpext(builder.call(fadd, [ir.Constant(_F32, 0.0), acc]), _F64)


def _make_tile(rows: int, cols: int) -> Callable[..., None]:
    """An intrinsic ``tile(a, i, b, j, sums)``: sums[r * cols + s] = diff(a[i + r], b[j + s]).

    ``a`` and ``b`` are C-contiguous 2-D arrays of one dtype (uint8 -> SAD, uint64 -> popcount of
    XOR, float32 -> sum of |a - b|) whose rows are a multiple of CHUNK_BYTES long; ``sums`` is a
    float64 array of at least rows * cols values.
    """

    @intrinsic
    def tile(typingctx, a, i, b, j, sums):  # type: ignore[no-untyped-def]
        kernel_dtypes = (types.uint8, types.uint64, types.float32)
        for x in (a, b):
            if not (isinstance(x, types.Array) and x.ndim == 2 and x.layout == "C" and x.dtype == a.dtype):
                return None
        if a.dtype not in kernel_dtypes or not (isinstance(sums, types.Array) and sums.dtype == types.float64):
            return None
        sig = types.void(a, i, b, j, sums)

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            path = simd_path()
            load_type, acc_type, op = _chunk_op(builder, signature.args[0].dtype, path)
            if _VECTOR_BYTES[path] == 64:
                # Explicit 512-bit vectors: without this LLVM splits them on CPUs tuned to prefer
                # 256-bit vectors (every AVX-512 Intel core); clang sets the same attribute for
                # 512-bit intrinsics. llvmlite only checks names of keyword attributes, so a
                # string attribute goes in through the underlying set.
                set.add(builder.function.attributes, '"min-legal-vector-width"="512"')
            arr_a = context.make_array(signature.args[0])(context, builder, args[0])
            arr_b = context.make_array(signature.args[2])(context, builder, args[2])
            arr_s = context.make_array(signature.args[4])(context, builder, args[4])
            row0 = context.cast(builder, args[1], signature.args[1], types.intp)
            col0 = context.cast(builder, args[3], signature.args[3], types.intp)
            width = cgutils.unpack_tuple(builder, arr_a.shape)[1]
            step = ir.Constant(_I64, load_type.count)

            def row_pointers(arr: cgutils.Structure, first: ir.Value, count: int) -> list[ir.Value]:
                start = builder.mul(first, width)
                offsets = [builder.add(start, builder.mul(ir.Constant(_I64, r), width)) for r in range(count)]
                return [builder.gep(arr.data, [offset]) for offset in offsets]

            pa = row_pointers(arr_a, row0, rows)
            pb = row_pointers(arr_b, col0, cols)
            accs = [cgutils.alloca_once_value(builder, ir.Constant(acc_type, None)) for _ in range(rows * cols)]
            add = builder.fadd if isinstance(acc_type.element, ir.FloatType) else builder.add
            n_chunks = builder.udiv(width, step)
            with cgutils.for_range(builder, n_chunks) as loop:
                offset = builder.mul(loop.index, step)

                def load(p: ir.Value) -> ir.Value:
                    return builder.load(builder.bitcast(builder.gep(p, [offset]), load_type.as_pointer()), align=1)

                va = [load(p) for p in pa]
                vb = [load(p) for p in pb]
                for r in range(rows):
                    for s in range(cols):
                        acc = accs[r * cols + s]
                        builder.store(add(builder.load(acc), op(builder, va[r], vb[s])), acc)
            for k, acc in enumerate(accs):
                builder.store(_reduce(builder, builder.load(acc)), builder.gep(arr_s.data, [ir.Constant(_I64, k)]))
            return context.get_dummy_value()

        return sig, codegen

    return tile


_tile_square = _make_tile(TILE, TILE)
_tile_single = _make_tile(1, 1)


@njit(cache=True, nogil=True)
def _panel(a: np.ndarray, b: np.ndarray, out: np.ndarray, start: int, stop: int, scale: float) -> None:
    """out[start:stop] for query rows start..stop: 4 x 4 tiles, then the leftover rows and columns."""
    sums = np.empty(TILE * TILE, np.float64)
    m = b.shape[0]
    j = 0
    while j + TILE <= m:
        i = start
        while i + TILE <= stop:
            _tile_square(a, i, b, j, sums)
            for r in range(TILE):
                for s in range(TILE):
                    out[i + r, j + s] = np.float32(sums[r * TILE + s] * scale)
            i += TILE
        for k in range(i, stop):
            for s in range(TILE):
                _tile_single(a, k, b, j + s, sums)
                out[k, j + s] = np.float32(sums[0] * scale)
        j += TILE
    for s in range(j, m):
        for k in range(start, stop):
            _tile_single(a, k, b, s, sums)
            out[k, s] = np.float32(sums[0] * scale)


@njit(parallel=True, cache=True, nogil=True)
def _simd_pairwise(a: np.ndarray, b: np.ndarray, out: np.ndarray, scale: float) -> None:
    """out[i, j] = scale * diff(a[i], b[j]) over panels of PANEL_ROWS query rows in parallel."""
    n = a.shape[0]
    for p in prange((n + PANEL_ROWS - 1) // PANEL_ROWS):
        _panel(a, b, out, p * PANEL_ROWS, min(n, (p + 1) * PANEL_ROWS), scale)


@njit(parallel=True, cache=True, nogil=True)
def band_extremes(block: np.ndarray, first: int, exclude: int, minima: np.ndarray, largest: np.ndarray) -> None:
    """For each row r of a block of a square self-difference matrix starting at row ``first``:
    lower ``minima[r]`` to its smallest finite value outside columns first + r +- ``exclude`` and
    raise ``largest[r]`` to its largest finite value (one pass, in parallel over rows)."""
    for r in prange(block.shape[0]):
        i = first + r
        low, high = minima[r], largest[r]
        for j in range(block.shape[1]):
            v = block[r, j]
            if np.isfinite(v):
                if v > high:
                    high = v
                if abs(i - j) > exclude and v < low:
                    low = v
        minima[r], largest[r] = low, high


def _padded(x: np.ndarray, dtype: type[np.generic]) -> np.ndarray:
    """C-contiguous ``x`` as ``dtype``, rows zero-padded to a multiple of CHUNK_BYTES."""
    per_chunk = CHUNK_BYTES // np.dtype(dtype).itemsize
    pad = -x.shape[1] % per_chunk
    if pad == 0:
        return np.ascontiguousarray(x, dtype=dtype)
    padded = np.zeros((x.shape[0], x.shape[1] + pad), dtype=dtype)
    padded[:, : x.shape[1]] = x
    return padded


@dataclass(frozen=True)
class _Reference:
    """The reference side prepared once for every query block: kernel-ready rows and extras."""

    metric: str
    rows: np.ndarray  # sqeuclidean: [b - mean, 1, |b - mean|^2] (float64), so one matrix product gives d
    mean: np.ndarray | None = None  # subtracted from both sides (sqeuclidean)
    largest: float = 0.0  # the largest |b - mean|^2 (sqeuclidean): what bounds a product's rounding


def _check_pair(a: np.ndarray, b: np.ndarray, metric: str) -> tuple[np.ndarray, np.ndarray, np.dtype]:
    """Both sides as 2-D arrays of equal row length, and the dtype the metric's kernel works in."""
    a, b = np.asarray(a), np.asarray(b)
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; expected one of {', '.join(METRICS)}")
    if a.ndim != 2 or b.ndim != 2:
        raise ValueError(f"rows must be 2-D arrays (frames x values), got shapes {a.shape} and {b.shape}")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"rows differ in length: {a.shape[1]} and {b.shape[1]} values")
    if metric == "hamming" and not a.dtype == b.dtype == np.uint8:
        raise ValueError(f"hamming needs uint8 rows of packed bits, got {a.dtype} and {b.dtype}")
    uint8 = metric in ("l1", "hamming") and a.dtype == b.dtype == np.uint8
    return a, b, np.dtype(np.uint8 if uint8 else np.float32)


def _kernel_rows(x: np.ndarray, metric: str, dtype: np.dtype) -> np.ndarray:
    """Rows as the SIMD kernel reads them (``l1``, ``hamming``): padded, packed bits as uint64."""
    rows = _padded(x, dtype.type)
    return rows.view(np.uint64) if metric == "hamming" else rows


def _prepare_reference(b: np.ndarray, metric: str, dtype: np.dtype) -> _Reference:
    if metric in ("l1", "hamming"):
        return _Reference(metric, _kernel_rows(b, metric, dtype))
    rows = np.asarray(np.asarray(b, dtype=np.float32), dtype=np.float64)  # float32 values, summed in float64
    if metric == "cosine":
        return _Reference(metric, _unit_rows(rows))
    # Centring both sides on the reference mean leaves the differences unchanged and shrinks the
    # norms, hence the cancellation in |a|^2 + |b|^2 - 2ab (GIST values are all positive).
    mean = rows.mean(axis=0) if len(rows) else np.zeros(rows.shape[1])
    centred = rows - mean
    norms = np.einsum("ij,ij->i", centred, centred)[:, None]
    return _Reference(metric, np.hstack([centred, np.ones_like(norms), norms]), mean=mean,
                      largest=float(norms.max()) if len(norms) else 0.0)


def _unit_rows(x: np.ndarray) -> np.ndarray:
    """Rows (float64) scaled to unit length; all-zero rows stay zero (difference 1 to everything)."""
    norms = np.sqrt(np.einsum("ij,ij->i", x, x))
    safe = np.where(norms > 0, norms, 1.0)
    return np.ascontiguousarray(x / safe[:, None])


def _product(a: np.ndarray, ref: _Reference, scale: float, out: np.ndarray, floor: np.ndarray) -> None:
    """out = scale * the metric's difference from ``a . ref.rows^T``, summed in float64 and rounded
    once to float32. BLAS sums in an order that depends on how many rows it is given at once and
    on the CPU; in float32 that order shows in the last digits, so a frame's row computed alone (a
    Localizer, frame by frame) differed from the same row in a batch's block, and a particle filter
    took the two apart (catgraph with gist on Nordland: 27 of 200 matches). In float64 the order's
    effect lies far below float32's rounding (0 of 715,200 values differed, rows alone against
    blocks of 200), except near 0, where float32 keeps every digit: a difference below ``floor``
    (each row of ``a``'s bound on the sum's rounding, :func:`_noise_floor`) is 0, as the same two
    rows' is exactly."""
    scratch = np.empty((min(PRODUCT_ROWS, len(a)), ref.rows.shape[0]))
    for start in range(0, len(a), PRODUCT_ROWS):
        part = scratch[:min(PRODUCT_ROWS, len(a) - start)]
        if len(part) == 1:  # a frame's row (a Localizer's): the matrix-vector product, reading each row once
            np.dot(ref.rows, a[start], out=part[0])
        else:
            np.matmul(a[start:start + len(part)], ref.rows.T, out=part)
        if ref.metric == "cosine":
            np.subtract(1.0, part, out=part)
            np.minimum(part, 2.0, out=part)
        np.copyto(part, 0.0, where=part < floor[start:start + len(part)])
        if scale != 1.0:
            part *= scale
        out[start:start + len(part)] = part


def _fill(a: np.ndarray, ref: _Reference, scale: float, out: np.ndarray) -> None:
    """out = scale * difference(a rows, reference rows)."""
    if ref.metric in ("l1", "hamming"):
        dtype = np.dtype(np.uint8) if ref.metric == "hamming" else ref.rows.dtype
        rows = _kernel_rows(a, ref.metric, dtype)
        if rows.shape[0] <= PANEL_ROWS:  # one panel: no parallel region to start and join (frame by frame)
            _panel(rows, ref.rows, out, 0, rows.shape[0], float(scale))
        else:
            _simd_pairwise(rows, ref.rows, out, float(scale))
        return
    rows = np.asarray(np.asarray(a, dtype=np.float32), dtype=np.float64)
    if ref.metric == "cosine":
        _product(_unit_rows(rows), ref, scale, out, _noise_floor(rows.shape[1], np.full((len(rows), 1), 2.0)))
    else:
        # [-2a, |a|^2, 1] . [b, 1, |b|^2] = |a|^2 + |b|^2 - 2ab in one BLAS call: no extra passes
        # over the output block (16 % faster at N = 20,000, docs/kernels.md).
        centred = rows - ref.mean
        norms = np.einsum("ij,ij->i", centred, centred)[:, None]
        _product(np.hstack([-2.0 * centred, norms, np.ones_like(norms)]), ref, scale, out,
                 _noise_floor(rows.shape[1], norms + ref.largest))


def _noise_floor(length: int, magnitude: np.ndarray) -> np.ndarray:
    """Per row, a bound on the rounding of a float64 product of ``length`` terms whose sums reach
    ``magnitude`` (|a|^2 + the largest |b|^2; 2 for unit rows): a difference below it is the order
    of the sums, not the rows (two equal rows gave 4e-13 or 0 by their block and BLAS's threads)."""
    return length * np.finfo(np.float64).eps * magnitude


class DifferencesTo:
    """Differences to one fixed set of reference rows, prepared for the kernel once.

    ``DifferencesTo(b, metric, scale)(a)`` is ``pairwise(a, b, metric, scale)``; a caller that
    compares many query rows with the same references (a map, frame by frame) pays the reference
    side's preparation (padding, centring, norms) only once.
    """

    def __init__(self, b: np.ndarray, metric: str, scale: float = 1.0, dtype: np.dtype | None = None) -> None:
        b = np.asarray(b)
        self._probe = b[:0]  # an empty row block of b's dtype and width, for checking queries
        self._dtype = dtype if dtype is not None else _check_pair(b[:0], b, metric)[2]
        self._ref = _prepare_reference(b, metric, self._dtype)
        self.metric, self.scale, self.shape = metric, float(scale), b.shape
        self.exact = self._dtype == np.uint8  # integer sums: the same values whatever the row blocks

    def __call__(self, a: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The len(a) x len(b) float32 differences (into ``out`` when given: C-contiguous float32)."""
        a, _, _ = _check_pair(a, self._probe, self.metric)
        if self._dtype == np.uint8 and a.dtype != np.uint8:
            raise ParameterError("a", f"rows of {a.dtype} cannot be compared with uint8 reference rows; give uint8 rows")
        shape = (a.shape[0], self.shape[0])
        if out is None:
            out = np.empty(shape, dtype=np.float32)
        elif out.shape != shape or out.dtype != np.float32 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous float32 array of shape {shape}")
        if out.size:
            _fill(a, self._ref, self.scale, out)
        return out


def pairwise(
    a: np.ndarray, b: np.ndarray, metric: str, scale: float = 1.0, out: np.ndarray | None = None
) -> np.ndarray:
    """The len(a) x len(b) float32 matrix of scale * difference between every row of a and of b.

    ``l1``: sum of |a - b| (uint8 rows use the SAD kernel; scale turns the sum into a mean);
    ``sqeuclidean``: sum of squared differences (float32, matrix-product form, negatives clamped);
    ``hamming``: differing bits of uint8-packed rows; ``cosine``: 1 - cosine similarity.
    ``out``, if given, must be a C-contiguous float32 array of that shape; it is filled and returned.
    """
    _, _, dtype = _check_pair(a, b, metric)
    return DifferencesTo(b, metric, scale, dtype)(a, out)


def pairwise_blocks(
    a: np.ndarray, b: np.ndarray, metric: str, scale: float = 1.0, block_rows: int = 1024
) -> Iterator[tuple[int, int, np.ndarray]]:
    """Yield (start, stop, block) with block = pairwise(a[start:stop], b, ...), one row block at a time.

    The reference side is prepared once; the same float32 buffer is reused for every block, so
    a consumer that keeps a block must copy it.
    """
    a, b, dtype = _check_pair(a, b, metric)
    if block_rows < 1:
        raise ValueError(f"block_rows must be at least 1, got {block_rows}")
    to_b = DifferencesTo(b, metric, scale, dtype)
    buffer = np.empty((min(block_rows, a.shape[0]), b.shape[0]), dtype=np.float32)
    for start in range(0, a.shape[0], block_rows):
        stop = min(start + block_rows, a.shape[0])
        yield start, stop, to_b(a[start:stop], buffer[: stop - start])


@njit(cache=True, nogil=True)
def _paired_sad(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The sum of absolute differences of each uint8 row of a to the same row of b, exact (as
    float64): a route's steps without the float64 copies of every row that numpy would make."""
    out = np.empty(a.shape[0], dtype=np.float64)
    for i in range(a.shape[0]):
        total = 0
        for k in range(a.shape[1]):
            total += abs(np.int32(a[i, k]) - np.int32(b[i, k]))
        out[i] = total
    return out


def _paired(a: np.ndarray, b: np.ndarray, metric: str) -> np.ndarray:
    """difference(a[i], b[i]) for every i, as float64 (rows of equal shape)."""
    if metric == "l1" and a.dtype == np.uint8:
        return _paired_sad(a, b)
    if metric == "hamming":
        return np.unpackbits(np.bitwise_xor(a, b), axis=1).sum(axis=1, dtype=np.float64)
    x, y = a.astype(np.float64), b.astype(np.float64)
    if metric == "l1":
        return np.abs(x - y).sum(axis=1)
    if metric == "sqeuclidean":
        return ((x - y) ** 2).sum(axis=1)
    norms = np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1)
    dots = np.einsum("ij,ij->i", x, y)
    return np.where(norms > 0, 1.0 - dots / np.where(norms > 0, norms, 1.0), 1.0)


def consecutive(a: np.ndarray, metric: str, scale: float = 1.0, block_rows: int = 4096) -> np.ndarray:
    """scale * difference of each row of ``a`` to the next (len(a) - 1 values, float32): a
    route's steps, with no N x N work (within float rounding of the kernels' values)."""
    a, _, _ = _check_pair(a, a, metric)
    out = np.empty(max(a.shape[0] - 1, 0), dtype=np.float32)
    for start in range(0, out.size, block_rows):
        stop = min(start + block_rows, out.size)
        out[start:stop] = scale * _paired(a[start:stop], a[start + 1:stop + 1], metric)
    return out
