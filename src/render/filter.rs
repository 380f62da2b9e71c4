//! Filter importance sampling: the table from which the kernels draw a camera sample's
//! offset from its pixel's centre along each axis ([`PixelFilter`]).
//!
//! The filter's weight is tabulated at N + 1 evenly spaced offsets across its support
//! (N = [`FILTER_TABLE_SIZE`]) and taken as linear between them; the table also holds the
//! cumulative mass at each of those offsets. A uniform number picks a segment by the
//! cumulative masses (a binary search) and a point within it by inverting the segment's
//! linear density, so the offsets follow the interpolated weight exactly: a tent filter
//! of even N exactly, a Gaussian within 1e-4 of its peak weight.
//!
//! Layout (floats, as the kernels read it, glsl/lib/integrator.glsl `filter_offset`): the
//! radius r, the weights at −r + 2rk/N (k = 0 ..= N), the normalised cumulative masses at
//! the same offsets (0 first, 1 last).

use crate::scene::PixelFilter;

/// Segments of the table ([`crate::constants::FILTER_TABLE_SIZE`]).
pub const FILTER_TABLE_SIZE: usize = crate::constants::FILTER_TABLE_SIZE as usize;

/// The sampling table of `filter` (see the module documentation), `None` for the box
/// filter, which the kernels sample as a uniform offset.
pub fn table(filter: PixelFilter) -> Option<Vec<f32>> {
    if filter == PixelFilter::Box {
        return None;
    }
    let n = FILTER_TABLE_SIZE;
    let r = f64::from(filter.radius());
    let x = |k: usize| -r + 2.0 * r * k as f64 / n as f64;
    let w: Vec<f64> = (0..=n).map(|k| filter.weight(x(k))).collect();
    let mut cdf = vec![0.0f64; n + 1];
    for k in 0..n {
        cdf[k + 1] = cdf[k] + 0.5 * (w[k] + w[k + 1]);
    }
    let total = cdf[n];
    let mut out = Vec::with_capacity(2 * n + 3);
    out.push(r as f32);
    out.extend(w.iter().map(|&v| v as f32));
    out.extend(cdf.iter().enumerate().map(|(k, &c)| if k == n { 1.0 } else { (c / total) as f32 }));
    Some(out)
}

/// The offset (pixels from the centre) that uniform number `u` in [0, 1) draws from
/// `table`: what the kernels compute (`filter_offset`), in the same float arithmetic.
pub fn sample(table: &[f32], u: f32) -> f32 {
    let n = FILTER_TABLE_SIZE;
    let (r, w, c) = (table[0], &table[1..n + 2], &table[n + 2..]);
    let (mut lo, mut hi) = (0, n);
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if c[mid] <= u {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let span = c[lo + 1] - c[lo];
    let v = if span > 0.0 { ((u - c[lo]) / span).clamp(0.0, 1.0) } else { 0.0 };
    let (w0, w1) = (w[lo], w[lo + 1]);
    let m = v * 0.5 * (w0 + w1);
    let den = w0 + (w0 * w0 + 2.0 * (w1 - w0) * m).max(0.0).sqrt();
    let t = if den > 0.0 { (2.0 * m / den).min(1.0) } else { 0.0 };
    r * (2.0 * (lo as f32 + t) / n as f32 - 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The filter's own mass in [a, b], by Simpson's rule on its weight.
    fn weight_mass(f: PixelFilter, a: f64, b: f64) -> f64 {
        let simpson = |a: f64, b: f64| {
            if b <= a {
                return 0.0;
            }
            let n = 20_000;
            let h = (b - a) / n as f64;
            (0..=n)
                .map(|i| {
                    f.weight(a + i as f64 * h)
                        * if i == 0 || i == n {
                            1.0
                        } else if i % 2 == 1 {
                            4.0
                        } else {
                            2.0
                        }
                })
                .sum::<f64>()
                * h
                / 3.0
        };
        let r = f64::from(f.radius());
        simpson(a.max(-r), b.min(r)) / simpson(-r, r)
    }

    /// Offsets drawn at evenly spaced numbers u (a quadrature of the sampled distribution)
    /// give every interval the filter's mass in it (to 1e-4, tails included), stay within
    /// the radius, grow with u and are symmetric; the box has no table.
    #[test]
    fn samples_follow_their_filters() {
        assert!(table(PixelFilter::Box).is_none());
        for f in
            [PixelFilter::Gaussian { stddev: 0.5 }, PixelFilter::Gaussian { stddev: 1.2 }, PixelFilter::Tent { radius: 1.0 }, PixelFilter::Tent { radius: 2.5 }]
        {
            let t = table(f).unwrap();
            assert_eq!(t.len(), 2 * FILTER_TABLE_SIZE + 3);
            const COUNT: usize = 200_000;
            let xs: Vec<f64> = (0..COUNT).map(|i| f64::from(sample(&t, (i as f32 + 0.5) / COUNT as f32))).collect();
            let r = f64::from(f.radius());
            assert!(xs.iter().all(|x| x.abs() <= r), "{f:?}: beyond the radius");
            assert!(xs.windows(2).all(|w| w[0] <= w[1]), "{f:?}: not increasing");
            assert!((xs[0] + xs[COUNT - 1]).abs() < 1e-3 && (xs[COUNT / 4] + xs[COUNT - 1 - COUNT / 4]).abs() < 1e-4, "{f:?}: not symmetric");
            for (a, b) in [(-0.5, 0.5), (0.0, 0.25), (0.5, 1.5), (-r, -0.6 * r), (0.75 * r, r), (0.9 * r, r)] {
                let got = xs.iter().filter(|&&x| x >= a && x < b).count() as f64 / COUNT as f64;
                let want = weight_mass(f, a, b);
                assert!((got - want).abs() < 1e-4, "{f:?}: [{a}, {b}] holds {got}, the filter {want}");
            }
        }
    }
}
