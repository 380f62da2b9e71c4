//! Spectra in RGB, as Mitsuba's RGB variants read them: a `wavelength:value` list, a
//! uniform value or a blackbody, integrated against the CIE 1931 2° colour-matching
//! functions and taken from XYZ to linear sRGB.
//!
//! - A reflectance (`bounded`) is weighted by the D65 illuminant and normalised by D65's
//!   luminance, so that a flat spectrum of 1 is white; the result is clamped to [0, 1].
//! - A radiance is integrated as it is, normalised by the integral of ȳ, so that a flat
//!   spectrum of 1 has a luminance of 1; negative channels become 0.
//!
//! A list is interpolated linearly between its wavelengths and is zero outside them.

/// The CIE 1931 2° standard observer's x̄, ȳ, z̄ and the CIE D65 illuminant's relative
/// spectral power, every 5 nm from 360 to 830 nm (CIE 015:2018; D65 held at its 780 nm value
/// beyond, where ȳ is below 1e-4).
const CIE: [[f32; 4]; 95] = [
    [0.0001299, 3.917e-06, 0.0006061, 46.6383],
    [0.0002321, 6.965e-06, 0.001086, 49.3637],
    [0.0004149, 1.239e-05, 0.001946, 52.0891],
    [0.0007416, 2.202e-05, 0.003486, 51.0323],
    [0.001368, 3.9e-05, 0.00645, 49.9755],
    [0.002236, 6.4e-05, 0.01055, 52.3118],
    [0.004243, 0.00012, 0.02005, 54.6482],
    [0.00765, 0.000217, 0.03621, 68.7015],
    [0.01431, 0.000396, 0.06785, 82.7549],
    [0.02319, 0.00064, 0.1102, 87.1204],
    [0.04351, 0.00121, 0.2074, 91.486],
    [0.07763, 0.00218, 0.3713, 92.4589],
    [0.13438, 0.004, 0.6456, 93.4318],
    [0.21477, 0.0073, 1.03905, 90.057],
    [0.2839, 0.0116, 1.3856, 86.6823],
    [0.3285, 0.01684, 1.62296, 95.7736],
    [0.34828, 0.023, 1.74706, 104.865],
    [0.34806, 0.0298, 1.7826, 110.936],
    [0.3362, 0.038, 1.77211, 117.008],
    [0.3187, 0.048, 1.7441, 117.41],
    [0.2908, 0.06, 1.6692, 117.812],
    [0.2511, 0.0739, 1.5281, 116.336],
    [0.19536, 0.09098, 1.28764, 114.861],
    [0.1421, 0.1126, 1.0419, 115.392],
    [0.09564, 0.13902, 0.81295, 115.923],
    [0.05795, 0.1693, 0.6162, 112.367],
    [0.03201, 0.20802, 0.46518, 108.811],
    [0.0147, 0.2586, 0.3533, 109.082],
    [0.0049, 0.323, 0.272, 109.354],
    [0.0024, 0.4073, 0.2123, 108.578],
    [0.0093, 0.503, 0.1582, 107.802],
    [0.0291, 0.6082, 0.1117, 106.296],
    [0.06327, 0.71, 0.07825, 104.79],
    [0.1096, 0.7932, 0.05725, 106.239],
    [0.1655, 0.862, 0.04216, 107.689],
    [0.22575, 0.91485, 0.02984, 106.047],
    [0.2904, 0.954, 0.0203, 104.405],
    [0.3597, 0.9803, 0.0134, 104.225],
    [0.43345, 0.99495, 0.00875, 104.046],
    [0.51205, 1.0, 0.00575, 102.023],
    [0.5945, 0.995, 0.0039, 100.0],
    [0.6784, 0.9786, 0.00275, 98.1671],
    [0.7621, 0.952, 0.0021, 96.3342],
    [0.8425, 0.9154, 0.0018, 96.0611],
    [0.9163, 0.87, 0.00165, 95.788],
    [0.9786, 0.8163, 0.0014, 92.2368],
    [1.0263, 0.757, 0.0011, 88.6856],
    [1.0567, 0.6949, 0.001, 89.3459],
    [1.0622, 0.631, 0.0008, 90.0062],
    [1.0456, 0.5668, 0.0006, 89.8026],
    [1.0026, 0.503, 0.00034, 89.5991],
    [0.9384, 0.4412, 0.00024, 88.6489],
    [0.85445, 0.381, 0.00019, 87.6987],
    [0.7514, 0.321, 0.0001, 85.4936],
    [0.6424, 0.265, 5e-05, 83.2886],
    [0.5419, 0.217, 3e-05, 83.4939],
    [0.4479, 0.175, 2e-05, 83.6992],
    [0.3608, 0.1382, 1e-05, 81.863],
    [0.2835, 0.107, -1.90582e-21, 80.0268],
    [0.2187, 0.0816, 0.0, 80.1207],
    [0.1649, 0.061, 0.0, 80.2146],
    [0.1212, 0.04458, 0.0, 81.2462],
    [0.0874, 0.032, 0.0, 82.2778],
    [0.0636, 0.0232, 0.0, 80.281],
    [0.04677, 0.017, 0.0, 78.2842],
    [0.0329, 0.01192, 0.0, 74.0027],
    [0.0227, 0.00821, 0.0, 69.7213],
    [0.01584, 0.005723, 0.0, 70.6652],
    [0.0113592, 0.004102, 0.0, 71.6091],
    [0.00811092, 0.002929, 0.0, 72.979],
    [0.00579035, 0.002091, 0.0, 74.349],
    [0.00410946, 0.001484, 0.0, 67.9765],
    [0.00289933, 0.001047, 0.0, 61.604],
    [0.00204919, 0.00074, 0.0, 65.7448],
    [0.00143997, 0.00052, 0.0, 69.8856],
    [0.000999949, 0.0003611, 0.0, 72.4863],
    [0.000690079, 0.0002492, 0.0, 75.087],
    [0.000476021, 0.0001719, 0.0, 69.3398],
    [0.000332301, 0.00012, 0.0, 63.5927],
    [0.000234826, 8.48e-05, 0.0, 55.0054],
    [0.00016615, 6e-05, 0.0, 46.4182],
    [0.000117413, 4.24e-05, 0.0, 56.6118],
    [8.30753e-05, 3e-05, 0.0, 66.8054],
    [5.87065e-05, 2.12e-05, 0.0, 65.0941],
    [4.15099e-05, 1.499e-05, 0.0, 63.3828],
    [2.93533e-05, 1.06e-05, 0.0, 63.3828],
    [2.06738e-05, 7.4657e-06, 0.0, 63.3828],
    [1.45598e-05, 5.2578e-06, 0.0, 63.3828],
    [1.0254e-05, 3.7029e-06, 0.0, 63.3828],
    [7.22146e-06, 2.6078e-06, 0.0, 63.3828],
    [5.08587e-06, 1.8366e-06, 0.0, 63.3828],
    [3.58165e-06, 1.2934e-06, 0.0, 63.3828],
    [2.52252e-06, 9.1093e-07, 0.0, 63.3828],
    [1.77651e-06, 6.4153e-07, 0.0, 63.3828],
    [1.25114e-06, 4.5181e-07, 0.0, 63.3828],
];

const CIE_MIN: f32 = 360.0;
const CIE_MAX: f32 = 830.0;
const STEP: f32 = 5.0;

/// Integration points over [CIE_MIN, CIE_MAX].
const SAMPLES: usize = 1000;

/// The CIE table at wavelength `nm` (inside [CIE_MIN, CIE_MAX]), interpolated linearly.
fn cie(nm: f32) -> [f32; 4] {
    let t = ((nm - CIE_MIN) / STEP).clamp(0.0, (CIE.len() - 1) as f32);
    let i = (t as usize).min(CIE.len() - 2);
    let f = t - i as f32;
    std::array::from_fn(|k| CIE[i][k] * (1.0 - f) + CIE[i + 1][k] * f)
}

/// ∫ value(λ) · (x̄, ȳ, z̄)(λ) [· D65(λ)] dλ over the CIE range, and the same for value = 1.
fn integrate(value: impl Fn(f32) -> Option<f32>, d65: bool) -> ([f64; 3], f64) {
    let (mut xyz, mut norm) = ([0.0f64; 3], 0.0f64);
    let dl = f64::from(CIE_MAX - CIE_MIN) / SAMPLES as f64;
    for i in 0..SAMPLES {
        let nm = CIE_MIN + (i as f32 + 0.5) * (CIE_MAX - CIE_MIN) / SAMPLES as f32;
        let c = cie(nm);
        let w = if d65 { f64::from(c[3]) } else { 1.0 };
        norm += w * f64::from(c[1]) * dl;
        if let Some(v) = value(nm) {
            for k in 0..3 {
                xyz[k] += f64::from(v) * w * f64::from(c[k]) * dl;
            }
        }
    }
    (xyz, norm)
}

/// Linear sRGB (Rec. 709 primaries, D65 white) of CIE XYZ.
fn xyz_to_srgb([x, y, z]: [f64; 3]) -> [f32; 3] {
    [
        (3.240479 * x - 1.537150 * y - 0.498535 * z) as f32,
        (-0.969256 * x + 1.875991 * y + 0.041556 * z) as f32,
        (0.055648 * x - 0.204043 * y + 1.057311 * z) as f32,
    ]
}

/// Whether a spectrum is a reflectance (bounded to [0, 1], seen under D65) or a radiance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpectrumKind {
    Reflectance,
    Radiance,
}

/// The RGB of a `wavelength:value` list (wavelengths in nm, increasing), and whether it
/// was outside the gamut and clamped.
pub fn list_to_rgb(points: &[(f32, f32)], kind: SpectrumKind) -> Result<([f32; 3], bool), String> {
    if points.len() < 2 {
        return Err("a wavelength:value list needs at least two entries".into());
    }
    if let Some(w) = points.windows(2).find(|w| w[1].0.partial_cmp(&w[0].0) != Some(std::cmp::Ordering::Greater)) {
        return Err(format!("wavelengths must increase ({} then {})", w[0].0, w[1].0));
    }
    let value = |nm: f32| -> Option<f32> {
        let i = points.partition_point(|p| p.0 <= nm);
        if i == 0 || (i == points.len() && nm > points[i - 1].0) {
            return None;
        }
        let (a, b) = if i == points.len() { (points[i - 2], points[i - 1]) } else { (points[i - 1], points[i]) };
        let t = (nm - a.0) / (b.0 - a.0);
        Some(a.1 + (b.1 - a.1) * t)
    };
    Ok(finish(integrate(value, kind == SpectrumKind::Reflectance), kind))
}

/// The RGB radiance of a blackbody at `kelvin`: Planck's law in W·m⁻²·sr⁻¹·nm⁻¹ (the units
/// of Mitsuba's spectral blackbody), integrated as a radiance.
pub fn blackbody(kelvin: f32) -> Result<[f32; 3], String> {
    if !(kelvin.is_finite() && kelvin > 0.0) {
        return Err(format!("temperature {kelvin} K is not positive"));
    }
    const H: f64 = 6.626_070_15e-34;
    const C: f64 = 299_792_458.0;
    const K: f64 = 1.380_649e-23;
    let planck = |nm: f32| {
        let l = f64::from(nm) * 1e-9;
        let b = 2.0 * H * C * C / (l.powi(5) * ((H * C / (l * K * f64::from(kelvin))).exp_m1()));
        Some((b * 1e-9) as f32)
    };
    Ok(finish(integrate(planck, false), SpectrumKind::Radiance).0)
}

fn finish((xyz, norm): ([f64; 3], f64), kind: SpectrumKind) -> ([f32; 3], bool) {
    let rgb = xyz_to_srgb(xyz.map(|v| v / norm));
    let (lo, hi) = match kind {
        SpectrumKind::Reflectance => (0.0, 1.0),
        SpectrumKind::Radiance => (0.0, f32::INFINITY),
    };
    let clamped = rgb.map(|v| v.clamp(lo, hi));
    // Rounding puts a flat reflectance of 1 a hair above 1: not worth a warning.
    (clamped, rgb.iter().zip(clamped).any(|(a, b)| (a - b).abs() > 1e-3))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f32; 3], b: [f32; 3], rel: f32) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() <= rel * y.abs().max(1e-3))
    }

    /// References: Mitsuba 3.6's scalar_rgb (`spectrum_list_to_srgb` through a diffuse
    /// reflectance and a constant emitter's radiance) and, for the blackbody, its
    /// scalar_spectral render of a constant emitter (1024 spp).
    #[test]
    fn spectra_match_mitsubas_rgb_conversion() {
        let flat = [(400.0, 1.0), (700.0, 1.0)];
        let (r, clamped) = list_to_rgb(&flat, SpectrumKind::Reflectance).unwrap();
        assert!(close(r, [0.995342, 0.999756, 0.994909], 0.01) && !clamped, "{r:?}");
        let (r, _) = list_to_rgb(&flat, SpectrumKind::Radiance).unwrap();
        assert!(close(r, [1.19969, 0.949521, 0.903443], 0.01), "{r:?}");
        let (r, _) = list_to_rgb(&[(360.0, 2.0), (830.0, 2.0)], SpectrumKind::Radiance).unwrap();
        assert!(close(r, [2.40977, 1.89646, 1.81853], 0.01), "{r:?}");
        // A step at 500 nm is out of gamut: clamped as Mitsuba clamps it.
        let step = [(400.0, 0.0), (500.0, 0.0), (500.1, 1.0), (700.0, 1.0)];
        let (r, clamped) = list_to_rgb(&step, SpectrumKind::Reflectance).unwrap();
        assert!(close(r, [1.0, 0.986163, 0.0], 0.01) && clamped, "{r:?}");
        let b = blackbody(6500.0).unwrap();
        assert!(close(b, [44053.4, 41448.3, 43976.3], 0.02), "{b:?}");
        let b = blackbody(3000.0).unwrap();
        assert!(close(b, [733.949, 350.098, 114.538], 0.02), "{b:?}");
    }

    #[test]
    fn bad_lists_are_refused() {
        assert!(list_to_rgb(&[(400.0, 1.0)], SpectrumKind::Radiance).is_err());
        assert!(list_to_rgb(&[(500.0, 1.0), (400.0, 1.0)], SpectrumKind::Radiance).is_err());
        assert!(blackbody(-1.0).is_err());
    }
}
