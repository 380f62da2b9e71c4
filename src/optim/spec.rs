//! Optimiser specs as `compare --optimisers` and job files name them:
//! `NAME[@KEY=VALUE]...`, e.g. `adam`, `adam@beta1=0.5@beta2=0.99`, `meta@step=snr@var=zero`.
//!
//! `@` separates the hyperparameters so that a spec holds no comma and a comma-separated
//! list of specs splits without quoting. Keys are the fields of [`AdamHyper`] (`beta1`,
//! `beta2`, `eps`) or [`MetaHyper`] (`decay_f`, `decay_d`, `eps`, `step` = snr|adam|bounded|wiener|newton,
//! `beta2`, `var` = zero|centred, `grow_f`, `dpi` = group|global, `fdvar` = scaled|raw, and
//! for `step` = newton `decay_h`, `sig`, `multiple` = none|bonferroni, `settle`, `trust`, `persist`, `shrink` = element|group, `curv` = rms|ls,
//! `curv_se`, `curv_floor`; `carry`, the least weight of the fresh primal image in the
//! carried one, `carry_weight` = fixed|variance, `carry_adjoint` = on|off), and for both the learning-rate schedule's
//! (`schedule` = constant|cosine|step, `warmup`, `horizon`, `floor`, `every`, `gamma`; see
//! [`super::schedule`]); the rest keep their defaults. The learning rate itself is a run
//! setting (`--lr`), not a hyperparameter.

use super::{AdamHyper, CarryWeight, CurvatureFit, FdVariance, MetaHyper, Multiple, OptimError, Optimiser, Shrink, StepNorm, StepRule, VarianceEstimate};
use std::str::FromStr;

/// An optimiser with its hyperparameters and the text that named it, which labels its
/// results (output directory, plot legend, table row).
#[derive(Clone, Debug, PartialEq)]
pub struct Spec {
    pub label: String,
    pub optimiser: Optimiser,
}

/// The meta-estimator with its default hyperparameters.
impl Default for Spec {
    fn default() -> Self {
        Spec { label: "meta".into(), optimiser: Optimiser::Meta(MetaHyper::default()) }
    }
}

impl Spec {
    /// A comma-separated list of specs (`meta,adam@beta1=0.5`), as `compare --optimisers`
    /// takes it.
    pub fn parse_list(text: &str) -> Result<Vec<Spec>, OptimError> {
        parse_list(text)
    }

    /// The label with every character that is awkward in a file name replaced by `_`.
    pub fn dir_name(&self) -> String {
        file_safe(&self.label)
    }
}

/// `text` with characters outside `[A-Za-z0-9._@=-]` replaced by `_`.
pub fn file_safe(text: &str) -> String {
    text.chars().map(|c| if c.is_ascii_alphanumeric() || "._@=-".contains(c) { c } else { '_' }).collect()
}

/// The keys each optimiser accepts besides the schedule's, for error messages.
fn keys(o: &Optimiser) -> &'static str {
    match o {
        Optimiser::Adam(_) => "beta1, beta2, eps",
        Optimiser::Meta(_) => "decay_f, decay_d, eps, step, beta2, var, grow_f, dpi, fdvar, decay_h, sig, multiple, settle, trust, persist, curv, curv_se, curv_floor, calib, shrink, carry, carry_weight, carry_adjoint",
    }
}

/// The option named `value` of a key with named options, or an error listing them.
fn choice<T: Copy>(key: &str, value: &str, options: &[(&str, T)]) -> Result<T, OptimError> {
    if let Some((_, v)) = options.iter().find(|(name, _)| *name == value) {
        return Ok(*v);
    }
    let names: Vec<&str> = options.iter().map(|(name, _)| *name).collect();
    let expected = match names.split_last() {
        Some((last, [])) => last.to_string(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
        None => String::new(),
    };
    Err(OptimError::BadHyper(format!("{key} = '{value}' (expected {expected})")))
}

/// Sets hyperparameter `key` of `optimiser` from `value`; `Ok(false)` for an unknown key.
pub fn set_key(optimiser: &mut Optimiser, key: &str, value: &str) -> Result<bool, OptimError> {
    if optimiser.schedule_mut().set(key, value)? {
        return Ok(true);
    }
    let number = || value.parse::<f64>().map_err(|_| OptimError::BadHyper(format!("{key} = '{value}' is not a number")));
    let slot = match (&mut *optimiser, key) {
        (Optimiser::Meta(h), "step") => {
            h.step = choice(
                key,
                value,
                &[("snr", StepRule::Snr), ("adam", StepRule::Adam), ("bounded", StepRule::Bounded), ("wiener", StepRule::Wiener), ("newton", StepRule::Newton)],
            )?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "var") => {
            h.variance = choice(key, value, &[("zero", VarianceEstimate::Zero), ("centred", VarianceEstimate::Centred)])?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "dpi") => {
            h.dpi = choice(key, value, &[("group", StepNorm::Group), ("global", StepNorm::Global)])?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "shrink") => {
            h.shrink = choice(key, value, &[("element", Shrink::Element), ("group", Shrink::Group)])?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "multiple") => {
            h.multiple = choice(key, value, &[("none", Multiple::None), ("bonferroni", Multiple::Bonferroni)])?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "curv") => {
            h.curv = choice(key, value, &[("rms", CurvatureFit::Rms), ("ls", CurvatureFit::Ls)])?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "carry_weight") => {
            h.carry_weight = choice(key, value, &[("fixed", CarryWeight::Fixed), ("variance", CarryWeight::Variance)])?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "carry_adjoint") => {
            h.carry_adjoint = choice(key, value, &[("on", true), ("off", false)])?;
            return Ok(true);
        }
        (Optimiser::Meta(h), "fdvar") => {
            h.fdvar = choice(key, value, &[("scaled", FdVariance::Scaled), ("raw", FdVariance::Raw)])?;
            return Ok(true);
        }
        (Optimiser::Adam(AdamHyper { beta1, .. }), "beta1") => beta1,
        (Optimiser::Adam(AdamHyper { beta2, .. }), "beta2") => beta2,
        (Optimiser::Adam(AdamHyper { eps, .. }), "eps") => eps,
        (Optimiser::Meta(MetaHyper { decay_f, .. }), "decay_f") => decay_f,
        (Optimiser::Meta(MetaHyper { decay_d, .. }), "decay_d") => decay_d,
        (Optimiser::Meta(MetaHyper { eps, .. }), "eps") => eps,
        (Optimiser::Meta(MetaHyper { beta2, .. }), "beta2") => beta2,
        (Optimiser::Meta(MetaHyper { grow_f, .. }), "grow_f") => grow_f,
        (Optimiser::Meta(MetaHyper { decay_h, .. }), "decay_h") => decay_h,
        (Optimiser::Meta(MetaHyper { sig, .. }), "sig") => sig,
        (Optimiser::Meta(MetaHyper { settle, .. }), "settle") => settle,
        (Optimiser::Meta(MetaHyper { trust, .. }), "trust") => trust,
        (Optimiser::Meta(MetaHyper { persist, .. }), "persist") => persist,
        (Optimiser::Meta(MetaHyper { curv_se, .. }), "curv_se") => curv_se,
        (Optimiser::Meta(MetaHyper { curv_floor, .. }), "curv_floor") => curv_floor,
        (Optimiser::Meta(MetaHyper { calib, .. }), "calib") => calib,
        (Optimiser::Meta(MetaHyper { carry, .. }), "carry") => carry,
        _ => return Ok(false),
    };
    *slot = number()?;
    Ok(true)
}

impl FromStr for Spec {
    type Err = OptimError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let label = s.trim();
        let bad = |why: String| OptimError::BadSpec(format!("'{label}': {why}"));
        let mut parts = label.split('@');
        let name = parts.next().unwrap_or_default();
        let mut optimiser: Optimiser = name.parse()?;
        let mut seen: Vec<&str> = Vec::new();
        for part in parts {
            let (key, value) = part.split_once('=').ok_or_else(|| bad(format!("'{part}' is not KEY=VALUE")))?;
            let (key, value) = (key.trim(), value.trim());
            if seen.contains(&key) {
                return Err(bad(format!("{key} given twice")));
            }
            seen.push(key);
            if !set_key(&mut optimiser, key, value).map_err(|e| bad(e.to_string()))? {
                return Err(bad(format!("unknown key '{key}' for {name} (expected {}, or the schedule's {})", keys(&optimiser), super::Schedule::KEYS)));
            }
        }
        optimiser.validate().map_err(|e| bad(e.to_string()))?;
        Ok(Spec { label: label.to_string(), optimiser })
    }
}

/// Parses a comma-separated list of specs; labels must be distinct, since each names an
/// output directory.
pub fn parse_list(list: &str) -> Result<Vec<Spec>, OptimError> {
    let mut specs: Vec<Spec> = Vec::new();
    for item in list.split(',') {
        if item.trim().is_empty() {
            return Err(OptimError::BadSpec(format!("list '{list}' has an empty entry")));
        }
        let spec: Spec = item.parse()?;
        if specs.iter().any(|s| s.dir_name() == spec.dir_name()) {
            return Err(OptimError::BadSpec(format!("'{}' is listed twice", spec.label)));
        }
        specs.push(spec);
    }
    Ok(specs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_names_and_keys() {
        let s: Spec = "adam@beta1=0.5@beta2=0.99".parse().unwrap();
        assert_eq!(s.optimiser, Optimiser::Adam(AdamHyper { beta1: 0.5, beta2: 0.99, ..Default::default() }));
        assert_eq!(s.label, "adam@beta1=0.5@beta2=0.99");
        let m: Spec = "meta@decay_f=0.99".parse().unwrap();
        assert_eq!(m.optimiser, Optimiser::Meta(MetaHyper { decay_f: 0.99, ..Default::default() }));
        let m: Spec = "meta@step=bounded@var=centred@grow_f=0.5@beta2=0.99@schedule=cosine@warmup=5".parse().unwrap();
        let Optimiser::Meta(h) = m.optimiser else { panic!() };
        assert_eq!((h.step, h.variance, h.grow_f, h.beta2), (StepRule::Bounded, VarianceEstimate::Centred, 0.5, 0.99));
        assert_eq!((h.schedule.decay, h.schedule.warmup), (super::super::Decay::Cosine, 5));
        let a: Spec = "adam@schedule=step@every=50@gamma=0.3".parse().unwrap();
        assert_eq!(a.optimiser.schedule().factor(50), 0.3);
        assert_eq!("meta".parse::<Spec>().unwrap().optimiser, Optimiser::Meta(MetaHyper::default()));
        let list = parse_list("meta,adam,adam@beta1=0.5").unwrap();
        assert_eq!(list.iter().map(|s| s.label.as_str()).collect::<Vec<_>>(), ["meta", "adam", "adam@beta1=0.5"]);
    }

    #[test]
    fn errors_name_the_problem() {
        let msg = |s: &str| s.parse::<Spec>().unwrap_err().to_string();
        assert!(msg("adam@decay_f=0.5").contains("unknown key 'decay_f' for adam"), "{}", msg("adam@decay_f=0.5"));
        assert!(msg("adam@beta1").contains("'beta1' is not KEY=VALUE"));
        assert!(msg("adam@beta1=x").contains("beta1 = 'x' is not a number"));
        assert!(msg("adam@beta1=1.5").contains("beta1 = 1.5"));
        assert!(msg("adam@eps=1@eps=2").contains("eps given twice"));
        assert!(msg("sgd").contains("unknown optimiser 'sgd'"));
        assert!(msg("meta@step=secant").contains("expected snr, adam, bounded, wiener or newton"));
        assert!(msg("meta@settle=2").contains("settle = 2"));
        assert!(msg("meta@carry=1.5").contains("carry = 1.5 is outside [0, 1]"));
        assert!(msg("adam@carry=0.1").contains("unknown key 'carry' for adam"));
        assert!(msg("meta@decay_h=1").contains("decay_h = 1"));
        assert!(msg("meta@sig=-1").contains("sig = -1"));
        assert!(msg("meta@calib=1").contains("calib = 1 is outside [0, 1)"));
        assert!(msg("meta@trust=0.5").contains("trust = 0.5 is outside [1, 1000]"));
        assert!(msg("meta@persist=-1").contains("persist = -1 is outside [0, 1000]"));
        assert!(msg("meta@curv=mean").contains("curv = 'mean' (expected rms or ls)"));
        assert!(msg("meta@curv_se=-1").contains("curv_se = -1 is outside [0, 1000]"));
        assert!(msg("meta@curv_floor=2").contains("curv_floor = 2 is outside [0, 1]"));
        assert!(msg("meta@curv_floor=nan").contains("curv_floor = NaN is outside [0, 1]"));
        let Optimiser::Meta(h) = "meta@curv_floor=0.1".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h, MetaHyper { curv_floor: 0.1, ..MetaHyper::default() });
        let Optimiser::Meta(h) = "meta@curv=ls@curv_se=3".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h, MetaHyper { curv: crate::optim::CurvatureFit::Ls, curv_se: 3.0, ..MetaHyper::default() });
        // The README's spelling of the defaults is the defaults.
        let spelled = "meta@step=newton@var=centred@fdvar=raw@dpi=group@grow_f=0@decay_f=0.9@decay_d=0.3@decay_h=0.9@sig=1.5@multiple=bonferroni@settle=0.3@trust=1@persist=0@curv=rms@curv_floor=0@shrink=element@calib=0@carry=0.01@carry_weight=variance@carry_adjoint=on";
        assert!(include_str!("../../README.md").contains(spelled));
        assert_eq!(spelled.parse::<Spec>().unwrap().optimiser, Optimiser::Meta(MetaHyper::default()));
        let Optimiser::Meta(h) = "meta@trust=4".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h, MetaHyper { trust: 4.0, ..MetaHyper::default() });
        let Optimiser::Meta(h) = "meta@calib=0.99".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h.calib, 0.99);
        let Optimiser::Meta(h) = "meta@step=newton@sig=2@settle=0.5@decay_h=0.8".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!((h.step, h.sig, h.settle, h.decay_h), (StepRule::Newton, 2.0, 0.5, 0.8));
        let Optimiser::Meta(h) = "meta@carry=0".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h.carry, 0.0);
        let Optimiser::Meta(h) = "meta".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!((h.carry, h.carry_weight), (0.01, crate::optim::CarryWeight::Variance));
        assert!(msg("meta@carry_weight=mean").contains("carry_weight = 'mean' (expected fixed or variance)"));
        assert!(msg("adam@carry_weight=variance").contains("unknown key 'carry_weight' for adam"));
        assert!(msg("meta@carry_adjoint=yes").contains("carry_adjoint = 'yes' (expected on or off)"));
        let Optimiser::Meta(h) = "meta@carry_adjoint=off".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h, MetaHyper { carry_adjoint: false, ..MetaHyper::default() });
        let Optimiser::Meta(h) = "meta@carry_weight=variance@carry=0.01".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!((h.carry_weight, h.carry), (crate::optim::CarryWeight::Variance, 0.01));
        assert!(msg("meta@var=mad").contains("expected zero or centred"));
        assert!(msg("meta@dpi=all").contains("expected group or global"));
        assert!(msg("meta@fdvar=log").contains("expected scaled or raw"));
        assert!(msg("meta@shrink=all").contains("expected element or group"));
        let Optimiser::Meta(h) = "meta@shrink=group".parse::<Spec>().unwrap().optimiser else { unreachable!() };
        assert_eq!(h.shrink, Shrink::Group);
        let Optimiser::Meta(h) = "meta@fdvar=raw".parse::<Spec>().unwrap().optimiser else { unreachable!() };
        assert_eq!(h.fdvar, FdVariance::Raw);
        let Optimiser::Meta(h) = "meta@dpi=global".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h.dpi, StepNorm::Global);
        assert!(msg("adam@step=adam").contains("unknown key 'step' for adam"));
        assert!(msg("meta@grow_f=2").contains("grow_f = 2"));
        assert!(msg("meta@schedule=cosine@floor=2").contains("floor = 2"));
        assert!(msg("adam@every=x").contains("every = 'x'"));
        assert!(parse_list("meta,,adam").unwrap_err().to_string().contains("empty entry"));
        assert!(parse_list("adam,adam").unwrap_err().to_string().contains("listed twice"));
    }
}
