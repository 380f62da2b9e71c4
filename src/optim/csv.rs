//! `optimiser.csv`: the optimiser diagnostics of every iteration and parameter group, one row
//! each, with the columns `iteration,group` and then [`Diagnostics::COLUMNS`].

use super::reference::Diagnostics;
use std::fmt::Write as _;
use std::path::Path;

/// The header line (with its newline).
pub fn header() -> String {
    format!("iteration,group,{}\n", Diagnostics::COLUMNS.join(","))
}

/// Appends the row of `group`'s diagnostics at `iteration` (the step's number, from 1).
pub fn push_row(out: &mut String, iteration: u32, group: &str, d: &Diagnostics) {
    let _ = write!(out, "{iteration},{}", crate::optim::spec::file_safe(group));
    // The values are float32 results (or counts): their shortest float32 form.
    for v in d.values() {
        let _ = write!(out, ",{}", v as f32);
    }
    out.push('\n');
}

/// Writes the file atomically: `steps[i]` holds step i + 1's (group name, diagnostics).
pub fn write(path: &Path, steps: &[Vec<(String, Diagnostics)>]) -> std::io::Result<()> {
    let mut out = header();
    for (i, groups) in steps.iter().enumerate() {
        for (name, d) in groups {
            push_row(&mut out, i as u32 + 1, name, d);
        }
    }
    crate::image::write_bytes_atomic(path, out.as_bytes())
}

/// Reads the rows back: (iteration, group, values in the order of [`Diagnostics::COLUMNS`]).
pub fn parse(text: &str) -> Vec<(u32, String, Vec<f64>)> {
    text.lines()
        .skip(1)
        .filter_map(|line| {
            let mut f = line.split(',');
            let it = f.next()?.parse().ok()?;
            let group = f.next()?.to_string();
            let values: Vec<f64> = f.map(|v| v.parse().unwrap_or(f64::NAN)).collect();
            (values.len() == Diagnostics::COLUMNS.len()).then_some((it, group, values))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip() {
        let d = Diagnostics { lr: 0.02, elements: 3, n_eff_mean: 4.5, rms_step: 1e-30, ..Default::default() };
        let mut text = header();
        push_row(&mut text, 7, "materials.red.base_color", &d);
        let rows = parse(&text);
        assert_eq!(rows.len(), 1);
        assert_eq!((rows[0].0, rows[0].1.as_str()), (7, "materials.red.base_color"));
        let as_f32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        assert_eq!(as_f32(&rows[0].2), as_f32(&d.values()));
        assert!(text.starts_with("iteration,group,lr,elements,n_eff_mean,"));
    }
}
