//! The networks' arithmetic in loops the compiler vectorises: a matrix-vector product written
//! as a sum of scaled columns (each an axpy over the output, no reduction to reorder), and
//! exp/sigmoid/tanh/SiLU as a branch-free polynomial (libm's `expf` is a call per element,
//! which no loop vectorises). [`fast!`] runs a kernel's step compiled for AVX2 and FMA when
//! the CPU has them (detected once by std, a load per call), its multiply-adds fused
//! ([`Madd`]); every function here is `#[inline(always)]` so that it is compiled into that
//! caller.
//!
//! Accuracy: `exp` is Cephes' `expf` polynomial (relative error about 2e-7 over the clamped
//! range), so sigmoid/tanh/SiLU are within a few float32 ulps of torch's.

/// `a b + c` (`madd(a, b, c)`), the way a kernel compiled for a CPU does it: [`Fused`] (one rounding, the FMA
/// instruction) where the CPU has FMA, [`Split`] elsewhere (a software `fmaf` would be a call
/// per element).
pub trait Madd {
    fn madd(a: f32, b: f32, c: f32) -> f32;
}

pub struct Fused;
pub struct Split;

impl Madd for Fused {
    #[inline(always)]
    fn madd(a: f32, b: f32, c: f32) -> f32 {
        a.mul_add(b, c)
    }
}

impl Madd for Split {
    #[inline(always)]
    fn madd(a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
}

/// `fast!(M => expr)`: evaluates `expr` with the type `M` (a [`Madd`]) chosen for this CPU,
/// compiled with AVX2 and FMA where the CPU has both (x86-64), else as it is.
macro_rules! fast {
    ($m:ident => $body:expr) => {{
        #[cfg(target_arch = "x86_64")]
        let r = if $crate::math::has_avx2_fma() {
            #[allow(dead_code)]
            type $m = $crate::math::Fused;
            // SAFETY: the CPU has AVX2 and FMA (checked just above).
            unsafe {
                $crate::math::avx2_fma(
                    #[inline(always)]
                    || $body,
                )
            }
        } else {
            #[allow(dead_code)]
            type $m = $crate::math::Split;
            $body
        };
        #[cfg(not(target_arch = "x86_64"))]
        let r = {
            #[allow(dead_code)]
            type $m = $crate::math::Split;
            $body
        };
        r
    }};
}
pub(crate) use fast;

/// Whether this CPU has AVX2 and FMA (std caches the detection: a load per call).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn has_avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// `f` inlined into a function compiled for AVX2 and FMA: its loops get 8-wide vectors.
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`has_avx2_fma`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn avx2_fma<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `y = b + W x` with `w_t` W's columns in blocks ([`columns`]).
#[inline(always)]
pub(crate) fn affine<M: Madd>(w_t: &[f32], b: &[f32], x: &[f32], y: &mut [f32]) {
    y.copy_from_slice(b);
    add_product::<M>(w_t, x, y);
}

/// Outputs per block of [`add_product`]: 8 AVX2 registers of accumulators (enough independent
/// additions in flight to hide the add's latency), held in registers across all the inputs.
const BLOCK: usize = 64;

/// The last block's width: the rows past the full blocks, rounded up to whole AVX2 registers.
fn rest_width(rows: usize) -> usize {
    (rows % BLOCK).div_ceil(8) * 8
}

/// `y += W x` with `w_t` W's columns in blocks ([`columns`]). Each block of outputs
/// accumulates over every input in registers before being stored, reading its weights in one
/// contiguous run. A column at a time over `y` would store and reload each output once per
/// input, a chain of store-to-load forwards: measured, that made the LSTM's 400 x 100 product
/// the step's cost, and the last 16 of its 400 gates done that way cost a quarter of the
/// product (2.7 -> 2.1 us on this VM), so the last, narrower block is held in registers too
/// ([`block`], one instance per width). The order of the additions, input by input, is the
/// same either way: the result is bit for bit the same.
#[inline(always)]
pub(crate) fn add_product<M: Madd>(w_t: &[f32], x: &[f32], y: &mut [f32]) {
    let (n, m) = (y.len(), x.len());
    let full = n - n % BLOCK;
    for (panel, out) in w_t[..full * m]
        .chunks_exact(BLOCK * m)
        .zip(y[..full].chunks_exact_mut(BLOCK))
    {
        block::<M, BLOCK>(panel, x, out);
    }
    let (panel, out) = (&w_t[full * m..], &mut y[full..]);
    match rest_width(n) {
        0 => {}
        8 => block::<M, 8>(panel, x, out),
        16 => block::<M, 16>(panel, x, out),
        24 => block::<M, 24>(panel, x, out),
        32 => block::<M, 32>(panel, x, out),
        40 => block::<M, 40>(panel, x, out),
        48 => block::<M, 48>(panel, x, out),
        _ => block::<M, 56>(panel, x, out),
    }
}

/// `out += W x` for one block of `out.len() <= W` outputs whose columns in `panel` are each
/// `W` long (zeros past `out.len()`): `W` accumulators, in registers for `W <= 64`.
#[inline(always)]
fn block<M: Madd, const W: usize>(panel: &[f32], x: &[f32], out: &mut [f32]) {
    let k = out.len().min(W);
    let mut acc = [0.0f32; W];
    acc[..k].copy_from_slice(&out[..k]);
    for (col, &xi) in panel.chunks_exact(W).zip(x) {
        let col: &[f32; W] = col.try_into().unwrap_or(&[0.0; W]);
        for (a, &w) in acc.iter_mut().zip(col) {
            *a = M::madd(w, xi, *a);
        }
    }
    out[..k].copy_from_slice(&acc[..k]);
}

/// W [rows][cols] (row-major) in the layout of [`add_product`]: for each block of [`BLOCK`]
/// rows, its columns one after the other (each `BLOCK` long), then the remaining rows'
/// columns, each padded with zeros to [`rest_width`] (at most 7 zeros a column).
pub(crate) fn columns(w: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let full = rows - rows % BLOCK;
    let width = rest_width(rows);
    let mut out = Vec::with_capacity(full * cols + width * cols);
    for start in (0..full).step_by(BLOCK) {
        for c in 0..cols {
            out.extend((start..start + BLOCK).map(|r| w[r * cols + c]));
        }
    }
    for c in 0..cols {
        out.extend((full..full + width).map(|r| if r < rows { w[r * cols + c] } else { 0.0 }));
    }
    out
}

/// e^x, branch-free (Cephes expf): x clamped to [-87, 88] (the float32 range; e^-87 is 1.6e-38,
/// e^88 is 1.7e38), x = n ln 2 + r with |r| <= ln 2 / 2, e^r by a degree-7 polynomial, 2^n
/// written into the exponent bits.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // 1.5 * 2^23: adding it rounds to a whole number, kept in the low mantissa bits
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 0.166_666_65)
        * r
        + 0.5;
    let y = p * r * r + r + 1.0;
    let k = (t.to_bits() as i32).wrapping_sub(ROUND.to_bits() as i32);
    y * f32::from_bits(((k + 127) << 23) as u32)
}

#[inline(always)]
pub(crate) fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// tanh x = 1 - 2 / (e^2x + 1) (absolute error about 1e-7 near 0, where the relative error of
/// this form grows: the networks use tanh's value, never its ratio to x).
#[inline(always)]
pub(crate) fn tanh(x: f32) -> f32 {
    1.0 - 2.0 / (exp(2.0 * x) + 1.0)
}

/// A layer's activation, applied in place over a slice.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Activation {
    Identity,
    Relu,
    Sigmoid,
    Tanh,
    Silu,
}

impl Activation {
    /// From the exporter's name (train's network_graphs.py writes these).
    pub fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "identity" => Self::Identity,
            "relu" => Self::Relu,
            "sigmoid" => Self::Sigmoid,
            "tanh" => Self::Tanh,
            "silu" => Self::Silu,
            _ => return None,
        })
    }

    #[inline(always)]
    pub fn apply(self, v: &mut [f32]) {
        match self {
            Self::Identity => {}
            Self::Relu => v.iter_mut().for_each(|x| *x = x.max(0.0)),
            Self::Sigmoid => v.iter_mut().for_each(|x| *x = sigmoid(*x)),
            Self::Tanh => v.iter_mut().for_each(|x| *x = tanh(*x)),
            Self::Silu => v.iter_mut().for_each(|x| *x *= sigmoid(*x)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_sigmoid_and_tanh_match_std_within_float32_ulps() {
        let mut worst = [0.0f64; 3];
        for i in -20_000..=20_000 {
            let x = i as f32 * 0.005; // -100..100
            let e = f64::from(x).exp();
            if e < 1e38 && e > 1e-37 {
                let rel = (f64::from(exp(x)) - e).abs() / e;
                worst[0] = worst[0].max(rel);
            }
            let s = 1.0 / (1.0 + (-f64::from(x)).exp());
            worst[1] = worst[1].max((f64::from(sigmoid(x)) - s).abs());
            worst[2] = worst[2].max((f64::from(tanh(x)) - f64::from(x).tanh()).abs());
        }
        assert!(worst[0] < 5e-7, "exp relative error {}", worst[0]);
        assert!(worst[1] < 2e-7, "sigmoid error {}", worst[1]);
        assert!(worst[2] < 3e-7, "tanh error {}", worst[2]);
        assert!(sigmoid(-1e30) >= 0.0 && sigmoid(1e30) == 1.0);
        assert!(tanh(1e30) == 1.0 && tanh(-1e30) == -1.0);
    }

    #[test]
    fn the_blocked_product_is_the_matrix_product() {
        // two blocks and a rest of 22 (padded to 24), and every rest width, x 7 inputs,
        // against a plain f64 product
        for rows in [150, 1, 8, 9, 25, 64, 100, 112, 120, 400] {
            product_matches(rows, 7);
        }
    }

    fn product_matches(rows: usize, cols: usize) {
        let w: Vec<f32> = (0..rows * cols)
            .map(|i| ((i * 37) % 23) as f32 * 0.1 - 1.1)
            .collect();
        let x: Vec<f32> = (0..cols).map(|i| i as f32 * 0.3 - 0.9).collect();
        let b: Vec<f32> = (0..rows).map(|i| i as f32 * 0.01).collect();
        let w_t = columns(&w, rows, cols);
        let (y, in_order) = fast!(M => {
            let mut y = vec![0.0; rows];
            affine::<M>(&w_t, &b, &x, &mut y);
            // one output at a time, input by input: the blocks must add in this order
            let in_order: Vec<f32> = (0..rows)
                .map(|r| (0..cols).fold(b[r], |a, c| M::madd(w[r * cols + c], x[c], a)))
                .collect();
            (y, in_order)
        });
        assert_eq!(y, in_order, "{rows} rows");
        for r in 0..rows {
            let want: f64 = f64::from(b[r])
                + (0..cols)
                    .map(|c| f64::from(w[r * cols + c]) * f64::from(x[c]))
                    .sum::<f64>();
            assert!(
                (f64::from(y[r]) - want).abs() < 1e-5,
                "row {r}: {} vs {want}",
                y[r]
            );
        }
    }

    #[test]
    fn the_column_product_is_the_matrix_product() {
        // W = [[1, 2, 3], [4, 5, 6]] (2 x 3), x = [1, -1, 2], b = [0.5, -0.5]
        let w_t = columns(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 2, 3);
        let mut y = [0.0; 2];
        affine::<Split>(&w_t, &[0.5, -0.5], &[1.0, -1.0, 2.0], &mut y);
        assert_eq!(y, [0.5 + 1.0 - 2.0 + 6.0, -0.5 + 4.0 - 5.0 + 12.0]);
        fast!(M => affine::<M>(&w_t, &[0.5, -0.5], &[1.0, 0.0, 0.0], &mut y));
        assert_eq!(y, [1.5, 3.5]);
    }
}
