//! The upper-triangle product for 3x3 blocks with AVX2 and FMA (x86-64, detected at run
//! time), on blocks stored contiguously (9 values each, row-major) in float64 or float32:
//!
//! * $y_j \mathrel{+}= A_{ij}^\top x_i = \sum_a (\text{row}_a A_{ij})\,x_{i,a}$: three
//!   broadcast FMAs into $y_j$;
//! * $y_i \mathrel{+}= A_{ij} x_j$: lane-wise products $\text{row}_a \odot x_j$ summed over
//!   the whole block row in three accumulators, reduced horizontally once per row, not
//!   once per block.
//!
//! A block row is loaded as 4 lanes: the fourth is the next value in memory, which meets
//! the zero pad lane of $x_j$ in the accumulators and lands in the unused pad lane of
//! $y_j$. The product is bound by memory traffic (perf: the block loads dominate), so the
//! float32 copy (36 bytes per block instead of 72) is what makes it faster
//! (benches/README.md, session 4).

/// A 3-vector padded with a zero lane.
pub(super) type Lane = [f64; 4];

/// True when the CPU runs [`rows_f64`] and [`rows_f32`].
pub(super) fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// One off-diagonal block of [`rows_f64`] / [`rows_f32`]: a macro, not a closure, so that
/// it is certainly compiled with AVX2 inside them.
macro_rules! block {
    ($load:path, $bp:ident, $index:ident, $xp:ident, $yp:ident, ($x0:ident, $x1:ident, $x2:ident),
     $at:expr, $c0:ident, $c1:ident, $c2:ident) => {{
        let at = $at;
        let j = *$index.add(at) as usize;
        let m = $bp.add(9 * at);
        let (r0, r1, r2) = ($load(m), $load(m.add(3)), $load(m.add(6)));
        let xj = _mm256_loadu_pd($xp.add(4 * j));
        $c0 = _mm256_fmadd_pd(r0, xj, $c0);
        $c1 = _mm256_fmadd_pd(r1, xj, $c1);
        $c2 = _mm256_fmadd_pd(r2, xj, $c2);
        let yj = $yp.add(4 * j);
        let mut v = _mm256_loadu_pd(yj);
        v = _mm256_fmadd_pd(r0, $x0, v);
        v = _mm256_fmadd_pd(r1, $x1, v);
        v = _mm256_fmadd_pd(r2, $x2, v);
        _mm256_storeu_pd(yj, v);
    }};
}

macro_rules! kernel {
    ($name:ident, $t:ty, $load:path, $doc:literal) => {
        #[doc = $doc]
        ///
        /// # Safety
        /// [`available`] must be true; every row `i` of `range` must start with its diagonal block
        /// (`indices[indptr[i]] == i`); `blocks` must hold 9 values per block of `indices` plus at
        /// least one more, all finite; every column must be `< x.len() == y.len()`; the pad lanes
        /// of `x` must be zero.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        pub(super) unsafe fn $name(
            indptr: &[usize],
            indices: &[u32],
            blocks: &[$t],
            x: &[Lane],
            range: (usize, usize),
            y: &mut [Lane],
        ) {
            use std::arch::x86_64::*;
            let (xp, yp) = (x.as_ptr().cast::<f64>(), y.as_mut_ptr().cast::<f64>());
            let bp = blocks.as_ptr();
            let index = indices.as_ptr();
            // SAFETY (whole body): the caller's contract keeps every pointer below in bounds.
            unsafe {
                for i in range.0..range.1 {
                    let (start, end) = (*indptr.get_unchecked(i), *indptr.get_unchecked(i + 1));
                    let xi = xp.add(4 * i);
                    let (x0, x1, x2) = (
                        _mm256_broadcast_sd(&*xi),
                        _mm256_broadcast_sd(&*xi.add(1)),
                        _mm256_broadcast_sd(&*xi.add(2)),
                    );
                    let m = bp.add(9 * start);
                    let xiv = _mm256_loadu_pd(xi);
                    // Two sets of accumulators: one FMA chain per row of the block is latency
                    // bound (4-5 cycles per block); alternating blocks halves that.
                    let mut a0 = _mm256_mul_pd($load(m), xiv);
                    let mut a1 = _mm256_mul_pd($load(m.add(3)), xiv);
                    let mut a2 = _mm256_mul_pd($load(m.add(6)), xiv);
                    let (mut b0, mut b1, mut b2) = (
                        _mm256_setzero_pd(),
                        _mm256_setzero_pd(),
                        _mm256_setzero_pd(),
                    );
                    let mut at = start + 1;
                    while at + 1 < end {
                        block!($load, bp, index, xp, yp, (x0, x1, x2), at, a0, a1, a2);
                        block!($load, bp, index, xp, yp, (x0, x1, x2), at + 1, b0, b1, b2);
                        at += 2;
                    }
                    if at < end {
                        block!($load, bp, index, xp, yp, (x0, x1, x2), at, a0, a1, a2);
                    }
                    a0 = _mm256_add_pd(a0, b0);
                    a1 = _mm256_add_pd(a1, b1);
                    a2 = _mm256_add_pd(a2, b2);
                    // Horizontal sums of a0, a1, a2 into lanes 0, 1, 2.
                    let t = _mm256_hadd_pd(a0, a1); // [a0 01, a1 01, a0 23, a1 23]
                    let u = _mm256_hadd_pd(a2, a2); // [a2 01, a2 01, a2 23, a2 23]
                    let low = _mm256_permute2f128_pd(t, u, 0x20);
                    let high = _mm256_permute2f128_pd(t, u, 0x31);
                    let yi = yp.add(4 * i);
                    _mm256_storeu_pd(
                        yi,
                        _mm256_add_pd(_mm256_loadu_pd(yi), _mm256_add_pd(low, high)),
                    );
                }
            }
        }
    };
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn load_f64(p: *const f64) -> std::arch::x86_64::__m256d {
    // SAFETY: the caller reads within `blocks`.
    unsafe { std::arch::x86_64::_mm256_loadu_pd(p) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn load_f32(p: *const f32) -> std::arch::x86_64::__m256d {
    use std::arch::x86_64::*;
    // SAFETY: the caller reads within `blocks`.
    unsafe { _mm256_cvtps_pd(_mm_loadu_ps(p)) }
}

kernel!(
    rows_f64,
    f64,
    load_f64,
    "Adds the products of block rows `range` to `y` ($y_i$ and, for the off-diagonal\nblocks, $y_j$), float64 blocks; `y` is not cleared. The pad lanes of `y` collect\ngarbage: only lanes 0..3 mean anything."
);
kernel!(
    rows_f32,
    f32,
    load_f32,
    "[`rows_f64`] on float32 blocks (accumulated in float64)."
);

/// Never called: [`available`] is false off x86-64.
#[cfg(not(target_arch = "x86_64"))]
macro_rules! kernel_stub {
    ($name:ident, $t:ty) => {
        /// Never called: [`available`] is false off x86-64.
        ///
        /// # Safety
        /// None needed; it panics.
        pub(super) unsafe fn $name(
            _indptr: &[usize],
            _indices: &[u32],
            _blocks: &[$t],
            _x: &[Lane],
            _range: (usize, usize),
            _y: &mut [Lane],
        ) {
            unreachable!("the AVX2 product runs only where `available()` is true")
        }
    };
}
#[cfg(not(target_arch = "x86_64"))]
kernel_stub!(rows_f64, f64);
#[cfg(not(target_arch = "x86_64"))]
kernel_stub!(rows_f32, f32);
