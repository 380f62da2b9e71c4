//! Statistics of Monte Carlo comparisons: means with standard errors, Hotelling's T² test
//! of a zero mean vector, and the tail of the F distribution it needs (through the
//! regularised incomplete beta function). Pure f64 functions, checked against closed forms
//! and tabulated quantiles in the tests below.

/// Mean and standard error of the mean (sample standard deviation over √n); the error is 0
/// for fewer than two values.
pub fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let m = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return (m, 0.0);
    }
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// Hotelling's one-sample T² test that i.i.d. vectors `samples` (n rows of k values) have
/// mean zero: T² = n·d̄ᵀ S⁻¹ d̄ with S the sample covariance. Unlike a sum of squared
/// per-element z-scores it accounts for the correlation between elements (the three
/// channels of one colour are estimated from the same paths). Under the null hypothesis
/// and normal rows, (n − k)/(k (n − 1))·T² follows F(k, n − k).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Hotelling {
    pub t2: f64,
    pub f: f64,
    pub dof1: usize,
    pub dof2: usize,
    pub p_value: f64,
}

/// `None` when there are too few rows (n < k + 2) or S is singular (an element that does
/// not vary).
pub fn hotelling(samples: &[Vec<f64>]) -> Option<Hotelling> {
    let n = samples.len();
    let k = samples.first()?.len();
    if k == 0 || n < k + 2 {
        return None;
    }
    let mean: Vec<f64> = (0..k).map(|j| samples.iter().map(|r| r[j]).sum::<f64>() / n as f64).collect();
    let mut s = vec![vec![0.0; k]; k];
    for r in samples {
        for i in 0..k {
            for j in 0..k {
                s[i][j] += (r[i] - mean[i]) * (r[j] - mean[j]) / (n - 1) as f64;
            }
        }
    }
    let x = cholesky_solve(s, &mean)?;
    let t2 = n as f64 * mean.iter().zip(&x).map(|(a, b)| a * b).sum::<f64>();
    let (dof1, dof2) = (k, n - k);
    let f = (dof2 as f64) / (dof1 as f64 * (n - 1) as f64) * t2;
    Some(Hotelling { t2, f, dof1, dof2, p_value: f_survival(f, dof1 as f64, dof2 as f64) })
}

/// Solves S x = b for a symmetric positive definite S by Cholesky factorisation; `None`
/// when S is not positive definite (relative to its diagonal).
fn cholesky_solve(mut s: Vec<Vec<f64>>, b: &[f64]) -> Option<Vec<f64>> {
    let k = b.len();
    for j in 0..k {
        let diag = s[j][j];
        let d = diag - s[j][..j].iter().map(|x| x * x).sum::<f64>();
        // A pivot that lost all but ~1e-12 of its diagonal is a dependent column (NaN fails
        // the comparison too).
        let independent = d > 1e-12 * diag && d.is_finite();
        if !independent {
            return None;
        }
        let d = d.sqrt();
        s[j][j] = d;
        for i in j + 1..k {
            let v = s[i][j] - s[i][..j].iter().zip(&s[j][..j]).map(|(a, b)| a * b).sum::<f64>();
            s[i][j] = v / d;
        }
    }
    let mut y = vec![0.0; k];
    for i in 0..k {
        let mut v = b[i];
        for p in 0..i {
            v -= s[i][p] * y[p];
        }
        y[i] = v / s[i][i];
    }
    let mut x = vec![0.0; k];
    for i in (0..k).rev() {
        let mut v = y[i];
        for p in i + 1..k {
            v -= s[p][i] * x[p];
        }
        x[i] = v / s[i][i];
    }
    Some(x)
}

/// P(F > f) for F ~ F(d1, d2): the regularised incomplete beta I_{d2/(d2 + d1 f)}(d2/2, d1/2).
pub fn f_survival(f: f64, d1: f64, d2: f64) -> f64 {
    if f.is_nan() {
        return f64::NAN;
    }
    if f <= 0.0 {
        return 1.0;
    }
    if f.is_infinite() {
        return 0.0;
    }
    incomplete_beta(d2 / (d2 + d1 * f), 0.5 * d2, 0.5 * d1)
}

/// ln Γ(x) for x > 0 (Lanczos approximation, g = 7, nine coefficients; relative error
/// below 1e-15 over the range used here).
pub fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x) Γ(1 − x) = π / sin(πx).
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + G + 0.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// The regularised incomplete beta function I_x(a, b), by its continued fraction
/// (evaluated with the modified Lentz method), using the symmetry
/// I_x(a, b) = 1 − I_{1−x}(b, a) where the fraction converges slowly.
pub fn incomplete_beta(x: f64, a: f64, b: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let ln_front = ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln();
    if x < (a + 1.0) / (a + b + 2.0) {
        ln_front.exp() * beta_fraction(x, a, b) / a
    } else {
        1.0 - ln_front.exp() * beta_fraction(1.0 - x, b, a) / b
    }
}

fn beta_fraction(x: f64, a: f64, b: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let mut c = 1.0;
    let mut d = 1.0 - (a + b) * x / (a + 1.0);
    if d.abs() < TINY {
        d = TINY;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..=300 {
        let m = m as f64;
        // Even step: d_{2m} = m (b − m) x / ((a + 2m − 1)(a + 2m)).
        let num = m * (b - m) * x / ((a + 2.0 * m - 1.0) * (a + 2.0 * m));
        d = 1.0 + num * d;
        d = if d.abs() < TINY { 1.0 / TINY } else { 1.0 / d };
        c = 1.0 + num / c;
        if c.abs() < TINY {
            c = TINY;
        }
        h *= d * c;
        // Odd step: d_{2m+1} = −(a + m)(a + b + m) x / ((a + 2m)(a + 2m + 1)).
        let num = -(a + m) * (a + b + m) * x / ((a + 2.0 * m) * (a + 2.0 * m + 1.0));
        d = 1.0 + num * d;
        d = if d.abs() < TINY { 1.0 / TINY } else { 1.0 / d };
        c = 1.0 + num / c;
        if c.abs() < TINY {
            c = TINY;
        }
        let step = d * c;
        h *= step;
        if (step - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

/// A number in [0, 1) from a counter (splitmix64): deterministic data for synthetic
/// scenes and tests.
pub fn unit_hash(i: u64) -> f32 {
    let mut x = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 40) as f32 / (1u64 << 24) as f32
}

/// Median of a non-empty list (0 for an empty one).
pub fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(|a, b| a.total_cmp(b));
    let m = values.len() / 2;
    if values.len() % 2 == 1 {
        values[m]
    } else {
        0.5 * (values[m - 1] + values[m])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn incomplete_beta_matches_closed_forms() {
        for &x in &[1e-6, 0.01, 0.3, 0.5, 0.77, 0.999] {
            // I_x(1, 1) = x; I_x(1, b) = 1 − (1 − x)^b; I_x(a, 1) = x^a.
            assert!((incomplete_beta(x, 1.0, 1.0) - x).abs() < 1e-13, "{x}");
            assert!((incomplete_beta(x, 1.0, 3.5) - (1.0 - (1.0 - x).powf(3.5))).abs() < 1e-13, "{x}");
            assert!((incomplete_beta(x, 4.0, 1.0) - x.powi(4)).abs() < 1e-13, "{x}");
            // I_x(1/2, 1/2) = (2/π) asin(√x).
            let arcsine = 2.0 / std::f64::consts::PI * x.sqrt().asin();
            assert!((incomplete_beta(x, 0.5, 0.5) - arcsine).abs() < 1e-12, "{x}");
        }
    }

    #[test]
    fn f_tail_matches_tabulated_quantiles() {
        // Upper 0.1 % points of F (tables of the F distribution): F(1, 10) = 21.04
        // (= t_10 two-sided 0.1 % point 4.587²), F(3, 30) = 7.054, F(6, 34) ≈ 4.86 is
        // checked through the t relation instead: F(1, ν) = t_ν².
        assert!((f_survival(21.04, 1.0, 10.0) - 1e-3).abs() < 2e-5);
        assert!((f_survival(7.054, 3.0, 30.0) - 1e-3).abs() < 2e-5);
        // P(F(1, 39) > t²) = 2 P(T_39 > t): t = 2.023 is the two-sided 5 % point.
        assert!((f_survival(2.023f64.powi(2), 1.0, 39.0) - 0.05).abs() < 2e-4);
        // F(2, ν) has the closed form P(F > f) = (1 + 2f/ν)^(−ν/2).
        for &f in &[0.1, 1.0, 3.0, 12.0] {
            let exact = (1.0 + 2.0 * f / 20.0f64).powf(-10.0);
            assert!((f_survival(f, 2.0, 20.0) - exact).abs() < 1e-12, "{f}");
        }
        assert_eq!(f_survival(0.0, 3.0, 5.0), 1.0);
        assert_eq!(f_survival(f64::INFINITY, 3.0, 5.0), 0.0);
    }

    /// Samples of a small deterministic generator (splitmix64) as normal deviates.
    fn normals(seed: u64, n: usize) -> Vec<f64> {
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let (u1, u2) = (next().max(1e-300), next());
                (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
            })
            .collect()
    }

    /// Correlated rows: element j = common + own noise. Under a zero mean the p-values are
    /// uniform (checked by their rejection rate at 5 %); a shift of one element's mean by
    /// its own noise's standard deviation is found at 40 rows in most trials at p < 1e-3
    /// (noncentrality ≈ 40 · 0.75 = 30 against F(4, 36)).
    #[test]
    fn hotelling_is_calibrated_under_correlation_and_finds_a_shift() {
        let (n, k) = (40, 4);
        let rows = |seed: u64, shift: f64| -> Vec<Vec<f64>> {
            let z = normals(seed, n * (k + 1));
            (0..n).map(|r| (0..k).map(|j| 3.0 * z[r * (k + 1)] + z[r * (k + 1) + 1 + j] + if j == 1 { shift } else { 0.0 }).collect()).collect()
        };
        let trials = 400;
        let rejected = (0..trials).filter(|&t| hotelling(&rows(t, 0.0)).unwrap().p_value < 0.05).count();
        let rate = rejected as f64 / trials as f64;
        // Binomial(400, 0.05): standard deviation 0.011.
        assert!((rate - 0.05).abs() < 0.035, "rejection rate under the null {rate}");
        let found = (0..100).filter(|&t| hotelling(&rows(1000 + t, 1.0)).unwrap().p_value < 1e-3).count();
        assert!(found >= 60, "a 1 σ shift of one element found in {found} of 100");
        // Too few rows, and an element that never varies.
        assert!(hotelling(&rows(1, 0.0)[..5]).is_none());
        let mut flat = rows(2, 0.0);
        flat.iter_mut().for_each(|r| r[2] = 1.0);
        assert!(hotelling(&flat).is_none());
    }

    #[test]
    fn mean_se_of_small_sets() {
        assert_eq!(mean_se(&[]), (0.0, 0.0));
        assert_eq!(mean_se(&[2.0]), (2.0, 0.0));
        let (m, se) = mean_se(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(m, 2.5);
        assert!((se - (5.0f64 / 3.0 / 4.0).sqrt()).abs() < 1e-15);
    }
}
