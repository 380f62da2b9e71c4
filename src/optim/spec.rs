//! Optimiser specs as `compare --optimisers` and job files name them:
//! `NAME[@KEY=VALUE]...`, e.g. `adam`, `adam@beta1=0.5@beta2=0.99`, `meta@step=snr@var=zero`,
//! `meta-seed@decay_f=0.5`. NAME is `adam`, `meta` (the meta-estimator's defaults) or
//! `meta-seed` (the meta-estimator in the seed's configuration, [`MetaHyper::seed`]).
//!
//! `@` separates the hyperparameters so that a spec holds no comma and a comma-separated
//! list of specs splits without quoting. The keys of each optimiser are in [`ADAM_KEYS`] and
//! [`META_KEYS`], and for both the learning-rate schedule's (`schedule` =
//! constant|cosine|step, `warmup`, `horizon`, `floor`, `every`, `gamma`; see
//! [`super::schedule`]); the rest keep their defaults. The learning rate itself is a run
//! setting (`--lr`), not a hyperparameter.

use super::{AdamHyper, CarryWeight, FdVariance, MetaHyper, OptimError, Optimiser, StepRule, VarianceEstimate};
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

    /// Every optimiser's hyperparameter keys with their values and what they do, one line
    /// each: the help text of a spec.
    pub fn keys_help() -> String {
        help()
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

/// One hyperparameter key of a spec: its name, the values it takes, what it does, and how
/// it is set. The tables below are the one declaration that both parses a spec and
/// documents it ([`help`]), so that no help text can go stale.
pub struct Key<H: 'static> {
    pub name: &'static str,
    /// `number`, or the names it takes (`snr|adam`).
    pub values: &'static str,
    pub help: &'static str,
    set: fn(&mut H, &str) -> Result<(), OptimError>,
}

/// `value` as a number for key `key`.
fn number(key: &str, value: &str) -> Result<f64, OptimError> {
    value.parse::<f64>().map_err(|_| OptimError::BadHyper(format!("{key} = '{value}' is not a number")))
}

/// A key that sets a number field.
macro_rules! number_key {
    ($h:ty, $name:ident, $help:literal) => {
        Key::<$h> {
            name: stringify!($name),
            values: "number",
            help: $help,
            set: |h, v| {
                h.$name = number(stringify!($name), v)?;
                Ok(())
            },
        }
    };
}

/// A key that sets a field to one of named options.
macro_rules! choice_key {
    ($h:ty, $name:literal, $field:ident, $help:literal, [$($option:literal => $value:expr),+ $(,)?]) => {
        Key::<$h> {
            name: $name,
            values: concat!($($option, "|"),+),
            help: $help,
            set: |h, v| {
                h.$field = choice($name, v, &[$(($option, $value)),+])?;
                Ok(())
            },
        }
    };
}

/// Adam's keys.
pub const ADAM_KEYS: &[Key<AdamHyper>] = &[
    number_key!(AdamHyper, beta1, "decay of the first moment's EMA"),
    number_key!(AdamHyper, beta2, "decay of the second moment's EMA"),
    number_key!(AdamHyper, eps, "added to the step's denominator"),
];

/// The meta-estimator's keys (for `meta` and `meta-seed`).
pub const META_KEYS: &[Key<MetaHyper>] = &[
    number_key!(MetaHyper, decay_f, "decay of the EMA of the fresh gradients' second moment"),
    number_key!(MetaHyper, decay_d, "decay of the EMA of the finite differences' second moment"),
    number_key!(MetaHyper, eps, "added to the step's denominator"),
    choice_key!(MetaHyper, "step", step, "how the estimate becomes a step", ["snr" => StepRule::Snr, "newton" => StepRule::Newton]),
    choice_key!(MetaHyper, "var", variance, "the fresh gradients' variance estimate", ["zero" => VarianceEstimate::Zero, "centred" => VarianceEstimate::Centred]),
    choice_key!(MetaHyper, "fdvar", fdvar, "the finite differences' variance model", ["scaled" => FdVariance::Scaled, "raw" => FdVariance::Raw]),
    number_key!(MetaHyper, decay_h, "step=newton: decay of each earlier secant's weight"),
    number_key!(MetaHyper, sig, "step=newton: the significance Newton's step needs, in standard deviations, for a group of one element"),
    number_key!(MetaHyper, settle, "step=newton: the fraction of the Wiener step taken where Newton's is shorter"),
    number_key!(MetaHyper, carry, "the least weight of the fresh render in the carried primal image (0: none carried)"),
    choice_key!(MetaHyper, "carry_weight", carry_weight, "how the fresh render is weighed into the carried image", ["fixed" => CarryWeight::Fixed, "variance" => CarryWeight::Variance]),
    choice_key!(MetaHyper, "carry_adjoint", carry_adjoint, "mix the adjoint pass's render into the carried image", ["on" => true, "off" => false]),
];

/// The keys each optimiser accepts besides the schedule's, for error messages.
fn keys(o: &Optimiser) -> String {
    let names: Vec<&str> = match o {
        Optimiser::Adam(_) => ADAM_KEYS.iter().map(|k| k.name).collect(),
        Optimiser::Meta(_) => META_KEYS.iter().map(|k| k.name).collect(),
    };
    names.join(", ")
}

/// Every optimiser's keys, one line each (`  NAME=VALUES  what it does`), then the
/// schedule's: the help text of the spec, made from the tables that parse it.
pub fn help() -> String {
    fn lines<H>(out: &mut String, keys: &[Key<H>]) {
        for k in keys {
            let values = k.values.trim_end_matches('|');
            out.push_str(&format!("    {}={values}: {}\n", k.name, k.help));
        }
    }
    let mut out = String::from("  adam\n");
    lines(&mut out, ADAM_KEYS);
    out.push_str("  meta, meta-seed\n");
    lines(&mut out, META_KEYS);
    out.push_str(&format!("  both: the learning-rate schedule's keys {}\n", super::Schedule::KEYS));
    out
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
    fn apply<H>(keys: &[Key<H>], h: &mut H, key: &str, value: &str) -> Result<bool, OptimError> {
        match keys.iter().find(|k| k.name == key) {
            Some(k) => (k.set)(h, value).map(|()| true),
            None => Ok(false),
        }
    }
    match optimiser {
        Optimiser::Adam(h) => apply(ADAM_KEYS, h, key, value),
        Optimiser::Meta(h) => apply(META_KEYS, h, key, value),
    }
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
        let m: Spec = "meta@step=snr@var=centred@schedule=cosine@warmup=5".parse().unwrap();
        let Optimiser::Meta(h) = m.optimiser else { panic!() };
        assert_eq!((h.step, h.variance), (StepRule::Snr, VarianceEstimate::Centred));
        assert_eq!((h.schedule.decay, h.schedule.warmup), (super::super::Decay::Cosine, 5));
        let a: Spec = "adam@schedule=step@every=50@gamma=0.3".parse().unwrap();
        assert_eq!(a.optimiser.schedule().factor(50), 0.3);
        assert_eq!("meta".parse::<Spec>().unwrap().optimiser, Optimiser::Meta(MetaHyper::default()));
        let list = parse_list("meta,adam,adam@beta1=0.5").unwrap();
        assert_eq!(list.iter().map(|s| s.label.as_str()).collect::<Vec<_>>(), ["meta", "adam", "adam@beta1=0.5"]);
    }

    #[test]
    fn meta_seed_is_the_seed_configuration() {
        let s: Spec = "meta-seed".parse().unwrap();
        assert_eq!((s.label.as_str(), s.optimiser), ("meta-seed", Optimiser::Meta(MetaHyper::seed())));
        let Optimiser::Meta(h) = "meta-seed@decay_f=0.5".parse::<Spec>().unwrap().optimiser else { panic!() };
        assert_eq!(h, MetaHyper { decay_f: 0.5, ..MetaHyper::seed() });
        // The seed spelled out with the default's keys.
        let spelled = "meta@step=snr@var=zero@fdvar=scaled@decay_d=0.9@sig=3@carry=0@carry_weight=fixed@carry_adjoint=off";
        assert_eq!(spelled.parse::<Spec>().unwrap().optimiser, Optimiser::Meta(MetaHyper::seed()));
        let list = parse_list("meta,meta-seed").unwrap();
        assert_eq!(list.iter().map(|s| s.dir_name()).collect::<Vec<_>>(), ["meta", "meta-seed"]);
        let msg = "meta-seed@beta1=0.5".parse::<Spec>().unwrap_err().to_string();
        assert!(msg.contains("unknown key 'beta1' for meta-seed") && msg.contains("carry_adjoint"), "{msg}");
    }

    #[test]
    fn help_and_parsing_come_from_one_table() {
        let text = help();
        for (name, values) in ADAM_KEYS.iter().map(|k| (k.name, k.values)).chain(META_KEYS.iter().map(|k| (k.name, k.values))) {
            assert!(text.contains(&format!("    {name}={}:", values.trim_end_matches('|'))), "{name} in:\n{text}");
            // Every key the help lists is one a spec takes: its first value parses (a
            // number key's 0.5 may be out of its range, which validation names).
            let value = if values == "number" { "0.5" } else { values.split('|').next().unwrap() };
            let optimiser = if ADAM_KEYS.iter().any(|k| k.name == name) && !META_KEYS.iter().any(|k| k.name == name) { "adam" } else { "meta" };
            match format!("{optimiser}@{name}={value}").parse::<Spec>() {
                Ok(_) => {}
                Err(e) => assert!(e.to_string().contains("outside"), "{name}={value}: {e}"),
            }
        }
        let unknown = "meta@nope=1".parse::<Spec>().unwrap_err().to_string();
        assert!(META_KEYS.iter().all(|k| unknown.contains(k.name)), "{unknown}");
    }

    #[test]
    fn removed_keys_are_unknown() {
        let msg = |s: &str| s.parse::<Spec>().unwrap_err().to_string();
        for key in ["beta2=0.99", "grow_f=0.5", "dpi=global", "multiple=none", "trust=4", "persist=2", "curv=ls", "curv_se=3", "curv_floor=0.1", "calib=0.99", "shrink=group"] {
            let name = key.split('=').next().unwrap();
            let m = msg(&format!("meta@{key}"));
            assert!(m.contains(&format!("unknown key '{name}' for meta (expected decay_f, decay_d, eps, step, var, fdvar")), "{m}");
        }
        for rule in ["adam", "bounded", "wiener"] {
            assert!(msg(&format!("meta@step={rule}")).contains("expected snr or newton"), "{rule}");
        }
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
        assert!(msg("meta@step=secant").contains("expected snr or newton"));
        assert!(msg("meta@settle=2").contains("settle = 2"));
        assert!(msg("meta@carry=1.5").contains("carry = 1.5 is outside [0, 1]"));
        assert!(msg("adam@carry=0.1").contains("unknown key 'carry' for adam"));
        assert!(msg("meta@decay_h=1").contains("decay_h = 1"));
        assert!(msg("meta@sig=-1").contains("sig = -1"));
        // docs/optimisers.md's spelling of the defaults is the defaults.
        let spelled = "meta@step=newton@var=centred@fdvar=raw@decay_f=0.9@decay_d=0.3@decay_h=0.9@sig=1.5@settle=0.3@carry=0.01@carry_weight=variance@carry_adjoint=on";
        assert!(include_str!("../../docs/optimisers.md").contains(spelled));
        assert_eq!(spelled.parse::<Spec>().unwrap().optimiser, Optimiser::Meta(MetaHyper::default()));
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
        assert!(msg("meta@fdvar=log").contains("expected scaled or raw"));
        let Optimiser::Meta(h) = "meta@fdvar=raw".parse::<Spec>().unwrap().optimiser else { unreachable!() };
        assert_eq!(h.fdvar, FdVariance::Raw);
        assert!(msg("adam@step=newton").contains("unknown key 'step' for adam"));
        assert!(msg("meta@schedule=cosine@floor=2").contains("floor = 2"));
        assert!(msg("adam@every=x").contains("every = 'x'"));
        assert!(parse_list("meta,,adam").unwrap_err().to_string().contains("empty entry"));
        assert!(parse_list("adam,adam").unwrap_err().to_string().contains("listed twice"));
    }
}
