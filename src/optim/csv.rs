//! `optimiser.csv` and `optimiser.png`: the optimiser diagnostics of every iteration and
//! parameter group, one row each, with the columns `iteration,group` and then
//! [`Diagnostics::COLUMNS`]; the plot shows n_eff, the RMS step, and the RMS of ⟨F⟩ with the
//! finite-difference term's standard deviation against the iteration.

use super::reference::Diagnostics;
use crate::report::{plot_panels, Curve, Panel};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::Path;

/// The rows of `optimiser.csv`: (iteration, group, diagnostics).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DiagLog {
    pub rows: Vec<(u32, String, Diagnostics)>,
}

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

impl DiagLog {
    /// Adds one step's diagnostics, one per group.
    pub fn push(&mut self, iteration: u32, groups: impl IntoIterator<Item = (String, Diagnostics)>) {
        self.rows.extend(groups.into_iter().map(|(g, d)| (iteration, g, d)));
    }

    /// The rows up to and including `iteration`.
    pub fn truncate(&mut self, iteration: u32) {
        self.rows.retain(|r| r.0 <= iteration);
    }

    /// The CSV text.
    pub fn to_csv(&self) -> String {
        let mut out = header();
        for (it, g, d) in &self.rows {
            push_row(&mut out, *it, g, d);
        }
        out
    }

    /// Reads the text [`Self::to_csv`] writes; rows that do not parse are an error.
    pub fn parse(text: &str) -> Result<DiagLog, String> {
        let mut rows = Vec::new();
        for (k, line) in text.lines().enumerate().skip(1) {
            let bad = || format!("line {}: not an optimiser.csv row", k + 1);
            let mut f = line.split(',');
            let it = f.next().and_then(|v| v.parse().ok()).ok_or_else(bad)?;
            let group = f.next().ok_or_else(bad)?.to_string();
            let values: Vec<f64> = f.map(|v| v.parse().map_err(|_| bad())).collect::<Result<_, _>>()?;
            let values: [f64; Diagnostics::COLUMNS.len()] = values.try_into().map_err(|_| bad())?;
            rows.push((it, group, Diagnostics::from_values(&values)));
        }
        Ok(DiagLog { rows })
    }

    /// Per group, (iteration, value) of `value`.
    fn series(&self, value: impl Fn(&Diagnostics) -> f64) -> Vec<(String, Vec<(f64, f64)>)> {
        let mut out: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
        for (it, g, d) in &self.rows {
            let point = (*it as f64, value(d));
            match out.iter_mut().find(|s| &s.0 == g) {
                Some(s) => s.1.push(point),
                None => out.push((g.clone(), vec![point])),
            }
        }
        out
    }
}

/// Writes `path` atomically: `steps[i]` holds step i + 1's (group name, diagnostics).
pub fn write(path: &Path, steps: &[Vec<(String, Diagnostics)>]) -> std::io::Result<()> {
    let mut log = DiagLog::default();
    for (i, groups) in steps.iter().enumerate() {
        log.push(i as u32 + 1, groups.iter().cloned());
    }
    crate::image::write_bytes_atomic(path, log.to_csv().as_bytes())
}

/// The shortest endings of the parameter groups' names that still tell them apart, for
/// legends: `materials.red.base_color` → `base_color` when it is the only base colour,
/// `red.base_color` beside `materials.green.base_color`.
fn short_names<'a>(groups: &[&'a str]) -> BTreeMap<&'a str, String> {
    let ending = |g: &str, parts: usize| {
        let all: Vec<&str> = g.split('.').collect();
        all[all.len().saturating_sub(parts)..].join(".")
    };
    let most = groups.iter().map(|g| g.split('.').count()).max().unwrap_or(1);
    let distinct: BTreeSet<&str> = groups.iter().copied().collect();
    let parts = (1..=most).find(|&k| distinct.iter().map(|g| ending(g, k)).collect::<BTreeSet<_>>().len() == distinct.len()).unwrap_or(most);
    distinct.into_iter().map(|g| (g, ending(g, parts))).collect()
}

/// Plots the diagnostics of one or more runs (`(label, log)`; an empty label for a single
/// run) into `path`: n_eff, RMS step, and RMS ⟨F⟩ with the FD term's standard deviation,
/// against the iteration, on log scales.
pub fn plot(path: &Path, title: &str, runs: &[(&str, &DiagLog)]) -> Result<(), String> {
    let groups: Vec<&str> = runs.iter().flat_map(|(_, log)| log.rows.iter().map(|r| r.1.as_str())).collect();
    let short = short_names(&groups);
    let name =
        |label: &str, group: &str, what: &str| [label, short[group].as_str(), what].iter().filter(|s| !s.is_empty()).copied().collect::<Vec<_>>().join(" ");
    let mut n_eff = Vec::new();
    let mut step = Vec::new();
    let mut noise = Vec::new();
    for (label, log) in runs {
        for (g, points) in log.series(|d| d.n_eff_mean) {
            n_eff.push(Curve { name: name(label, &g, ""), points });
        }
        for (g, points) in log.series(|d| d.rms_step) {
            step.push(Curve { name: name(label, &g, ""), points });
        }
        for (g, points) in log.series(|d| d.rms_f) {
            noise.push(Curve { name: name(label, &g, "<F>"), points });
        }
        for (g, points) in log.series(|d| d.sd_fd) {
            noise.push(Curve { name: name(label, &g, "FD sd"), points });
        }
    }
    let panels = [
        Panel { y_label: "n_eff (mean)".into(), curves: &n_eff },
        Panel { y_label: "RMS step".into(), curves: &step },
        Panel { y_label: "RMS <F>, FD sd".into(), curves: &noise },
    ];
    plot_panels(path, title, "iteration", &panels, (800, 1100))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip() {
        let d = Diagnostics { lr: 0.02, elements: 3, n_eff_mean: 4.5, rms_step: 1e-30, ..Default::default() };
        let mut log = DiagLog::default();
        log.push(7, [("materials.red.base_color".to_string(), d)]);
        log.push(8, [("materials.red.base_color".to_string(), d)]);
        let text = log.to_csv();
        assert!(text.starts_with("iteration,group,lr,elements,n_eff_mean,"));
        let mut back = DiagLog::parse(&text).unwrap();
        assert_eq!(back.rows.len(), 2);
        assert_eq!((back.rows[0].0, back.rows[0].1.as_str()), (7, "materials.red.base_color"));
        let as_f32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        assert_eq!(as_f32(&back.rows[0].2.values()), as_f32(&d.values()));
        back.truncate(7);
        assert_eq!(back.rows.len(), 1);
        assert!(DiagLog::parse("h\n1,g,2").unwrap_err().contains("line 2"));
    }

    #[test]
    fn legend_names_tell_groups_apart() {
        let names = short_names(&["materials.left.base_color", "materials.right.base_color", "materials.left.base_color"]);
        assert_eq!(names["materials.left.base_color"], "left.base_color");
        assert_eq!(names["materials.right.base_color"], "right.base_color");
        let names = short_names(&["materials.ribbon.base_color", "materials.ribbon.roughness"]);
        assert_eq!(names["materials.ribbon.roughness"], "roughness");
        let names = short_names(&["a.x", "x"]);
        assert_eq!((names["a.x"].as_str(), names["x"].as_str()), ("a.x", "x"));
    }
}
