//! Run settings: what an optimisation run does, given in layers.
//!
//! Every setting is declared once, in the `settings!` invocation below: its name, type,
//! default and documentation. From that one declaration come
//! - [`Settings`], one layer of settings, every value optional: the same struct is the
//!   command line's flags (which the binary declares from [`Settings::FIELDS`] and sets
//!   with [`Settings::set`]), the scene's `[optimise]` table and a job file's shared
//!   settings and `[[jobs]]` entries (serde, through [`SettingsTable`], which keeps toml's
//!   line numbers in errors), and a binding's keywords;
//! - [`RunSettings`], the settings of one run with every value resolved;
//! - the per-setting plumbing: layering ([`Settings::then`]), key lists, table
//!   deserialization, the list of changed settings reported on `--resume`.
//!
//! A new setting is one entry in the invocation (and its range in [`Settings::validate`]
//! if it has one). Layers, lowest first: defaults, the scene's `[optimise]`, a job file's
//! shared settings, a job's own, the command line. Two rules join layers:
//! - a layer that gives `time_budget` without `iterations` drops the iteration count of
//!   the layers below it (the run then lasts for the budget alone), and the default of
//!   500 iterations applies only to a run without a budget;
//! - a learning rate given outside the scene replaces the scene's per-parameter rates.

use crate::optim::spec::Spec;
use crate::optim::{Optimiser, Schedule};
use serde::de::{self, DeserializeSeed, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};
use std::fmt;
use std::str::FromStr;

/// The image loss.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Loss {
    /// Mean squared difference.
    #[default]
    L2,
    /// Mean absolute difference.
    L1,
    /// Squared difference over (target² + 0.01).
    RelativeL2,
}

impl Loss {
    pub const ALL: [Loss; 3] = [Loss::L2, Loss::L1, Loss::RelativeL2];

    pub fn as_str(self) -> &'static str {
        match self {
            Self::L2 => "l2",
            Self::L1 => "l1",
            Self::RelativeL2 => "relative_l2",
        }
    }
}

impl Loss {
    /// The loss of `image` against `target` (the mean over pixels and channels) and its
    /// gradient with respect to the image, dL/dImage: what the `loss` kernel computes
    /// (glsl/loss.comp), in double precision. The images have the same size.
    ///
    /// ```
    /// use vkinverse::{Image, Loss};
    /// let (value, adjoint) = Loss::L2.evaluate(&Image::filled(2, 2, [1.0; 3]), &Image::filled(2, 2, [0.5; 3]));
    /// assert_eq!(value, 0.25);
    /// assert_eq!(adjoint.data[0], [2.0 * 0.5 / 12.0; 3]);
    /// ```
    pub fn evaluate(self, image: &crate::image::Image, target: &crate::image::Image) -> (f64, crate::image::Image) {
        let scale = 1.0 / (3.0 * image.data.len().max(1) as f64);
        let mut total = 0.0;
        let data = image
            .data
            .iter()
            .zip(&target.data)
            .map(|(i, t)| {
                [0, 1, 2].map(|c| {
                    let (i, t) = (f64::from(i[c]), f64::from(t[c]));
                    let d = i - t;
                    let (value, gradient) = match self {
                        Loss::L2 => (d * d, 2.0 * d),
                        Loss::L1 => (
                            d.abs(),
                            if d > 0.0 {
                                1.0
                            } else if d < 0.0 {
                                -1.0
                            } else {
                                0.0
                            },
                        ),
                        Loss::RelativeL2 => {
                            let w = 1.0 / (t * t + 0.01);
                            (d * d * w, 2.0 * d * w)
                        }
                    };
                    total += value;
                    (gradient * scale) as f32
                })
            })
            .collect();
        (total * scale, crate::image::Image { width: image.width, height: image.height, data })
    }
}

impl fmt::Display for Loss {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Loss {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL.into_iter().find(|l| l.as_str() == s).ok_or_else(|| format!("unknown loss \"{s}\" (expected l2, l1 or relative_l2)"))
    }
}

/// Seeds are `u64` everywhere; the GPU's random-number streams take 32 bits, so this hashes
/// a seed down explicitly: the low 32 bits xor the high 32 bits times the 32-bit golden
/// ratio. Seeds below 2³² are used as they are, and seeds that differ only in their high
/// bits give different streams.
pub fn gpu_seed(seed: u64) -> u32 {
    (seed as u32) ^ ((seed >> 32) as u32).wrapping_mul(0x9E37_79B9)
}

/// The first type of a list: the resolved type of a setting, which is its layer type unless
/// the declaration names another.
macro_rules! first_type {
    ($t:ty) => {
        $t
    };
    ($t:ty, $u:ty) => {
        $t
    };
}

/// How a setting is given on a command line: a flag with a value (shown as `value`), or a
/// switch that may take `true` or `false` (`--fd-two-trace`, `--fd-two-trace false`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arity {
    Value(&'static str),
    Switch,
}

/// One setting as a command line or a binding declares it: its key (`fd_spp`; the flag is
/// `--fd-spp`), how it takes its value and its help text. Made from the one declaration
/// that also parses and documents it, so that no help text can go stale.
#[derive(Clone, Copy, Debug)]
pub struct Field {
    pub key: &'static str,
    pub arity: Arity,
    pub help: &'static str,
}

impl Field {
    /// The key as a command-line flag: `--fd-spp`.
    pub fn flag(&self) -> String {
        format!("--{}", self.key.replace('_', "-"))
    }
}

/// Declares every setting: `NAME: LAYER_TYPE [=> RESOLVED_TYPE] = DEFAULT, ARITY;` with its
/// doc comment, which is its help text. The resolved type must be `From` the layer type,
/// and the layer type `FromStr` (its text on a command line).
macro_rules! settings {
    ($(
        $(#[doc = $doc:literal])*
        $name:ident : $ty:ty $(=> $resolved:ty)? = $default:expr, $arity:expr;
    )*) => {
        /// One layer of run settings (command line, scene `[optimise]`, job file, a
        /// binding's keywords); `None` leaves the value to the layers below.
        #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct Settings {
            $(
                $(#[doc = $doc])*
                #[serde(default, skip_serializing_if = "Option::is_none")]
                pub $name: Option<$ty>,
            )*
        }

        /// The settings of one run, every value resolved.
        #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
        pub struct RunSettings {
            $( $(#[doc = $doc])* pub $name: first_type!($($resolved,)? $ty), )*
            /// Whether a learning rate was given outside the scene, replacing the scene's
            /// per-parameter rates.
            pub lr_replaces_param_rates: bool,
        }

        impl Settings {
            /// Every setting's key, as in TOML; on the command line `_` is `-`.
            pub const KEYS: &'static [&'static str] = &[$(stringify!($name)),*];

            /// Every setting with its arity and help text, in declaration order.
            pub const FIELDS: &'static [Field] = &[$(Field {
                key: stringify!($name),
                arity: $arity,
                help: concat!($($doc, "\n"),*),
            }),*];

            /// Sets setting `key` from its text (as a command line gives it); the error
            /// names what is wrong with the value. An unknown key is an error too.
            ///
            /// ```
            /// let mut settings = vkinverse::Settings::default();
            /// settings.set("fd_spp", "2").unwrap();
            /// settings.set("optimiser", "adam@beta1=0.5").unwrap();
            /// assert_eq!(settings.fd_spp, Some(2));
            /// assert!(settings.set("spp", "two").is_err());
            /// ```
            pub fn set(&mut self, key: &str, text: &str) -> Result<(), Invalid> {
                match key {
                    $( stringify!($name) => {
                        let value = text.trim().parse::<$ty>().map_err(|e| Invalid { key: stringify!($name), message: format!("'{text}': {e}") })?;
                        self.$name = Some(value);
                    } )*
                    _ => return Err(Invalid { key: "setting", message: format!("unknown setting '{key}' (expected one of {})", Self::KEYS.join(", ")) }),
                }
                Ok(())
            }

            /// `self` with every value that `over` sets replaced by `over`'s.
            fn overlay(&self, over: &Settings) -> Settings {
                Settings { $( $name: over.$name.clone().or_else(|| self.$name.clone()), )* }
            }

            /// Every value, the default where none is set.
            fn fill(&self, lr_replaces_param_rates: bool) -> RunSettings {
                RunSettings {
                    $( $name: self.$name.clone().map_or_else(|| $default, Into::into), )*
                    lr_replaces_param_rates,
                }
            }

            /// Reads the value of setting `key` from `map`; false if `key` is no setting.
            fn read_value<'de, A: MapAccess<'de>>(&mut self, key: &str, map: &mut A) -> Result<bool, A::Error> {
                match key {
                    $( stringify!($name) => self.$name = Some(map.next_value()?), )*
                    _ => return Ok(false),
                }
                Ok(true)
            }
        }

        impl RunSettings {
            /// `key: old -> new` for every setting that differs between `self` and `new`.
            pub fn changes(&self, new: &RunSettings) -> Vec<String> {
                let show = |v: serde_json::Value| match v {
                    serde_json::Value::Null => "unset".to_string(),
                    serde_json::Value::String(s) => s,
                    other => other.to_string(),
                };
                let mut out = Vec::new();
                $(
                    if self.$name != new.$name {
                        let (a, b) = (serde_json::to_value(&self.$name), serde_json::to_value(&new.$name));
                        out.push(format!("{}: {} -> {}", stringify!($name), show(a.unwrap_or_default()), show(b.unwrap_or_default())));
                    }
                )*
                out
            }
        }
    };
}

settings! {
    /// Optimiser spec `NAME[@KEY=VALUE]...`: meta, meta-seed (the seed's configuration) or adam, with hyperparameters
    /// (`adam@beta1=0.5`).
    optimiser: Spec = Spec::default(), Arity::Value("SPEC");
    /// Image loss: l2, l1 or relative_l2.
    loss: Loss = Loss::L2, Arity::Value("LOSS");
    /// Iterations (with a time budget: at most this many).
    iterations: u32 => Option<u32> = Some(500), Arity::Value("N");
    /// Stop after this many seconds of optimisation (instead of, or on top of, iterations);
    /// an iteration of the mean length so far that would end past it is not started.
    time_budget: f64 => Option<f64> = None, Arity::Value("SEC");
    /// Samples per pixel of the gradient estimate's adjoint pass.
    spp: u32 = 2, Arity::Value("N");
    /// Samples per pixel of the meta-estimator's finite-difference sample.
    fd_spp: u32 = 1, Arity::Value("N");
    /// The meta-estimator's finite-difference sample traces every N-th pixel of each row
    /// (2: a checkerboard that moves every iteration), each weighted N times: 1/N of its
    /// cost, N times its variance. Above 1 the losses read each iteration's own primal
    /// render (meta's carried image needs the sample on every pixel).
    fd_stride: u32 = 1, Arity::Value("N");
    /// Samples per pixel of the gradient estimate's primal render.
    primal_spp: u32 = 4, Arity::Value("N");
    /// Samples per pixel of the target images rendered from the scene's reference values
    /// (a sensor without `target_image`); a glossy scene may need more for a target whose
    /// noise does not move the loss's optimum.
    target_spp: u32 = 1024, Arity::Value("N");
    /// Learning rate: the typical parameter change per iteration (given here, it replaces
    /// the scene's per-parameter rates).
    lr: f64 = 0.02, Arity::Value("X");
    /// Learning-rate schedule `DECAY[@KEY=VALUE]...`: constant, cosine (keys horizon, floor)
    /// or step (every, gamma), each with an optional warmup; given, it replaces the
    /// optimiser spec's own. A cosine without a horizon decays over the run's iterations.
    schedule: Schedule => Option<Schedule> = None, Arity::Value("SCHEDULE");
    /// Seed of every random-number stream of the run.
    seed: u64 = 0, Arity::Value("S");
    /// Commit a checkpoint every N iterations (and at the end).
    checkpoint_every: u32 = 50, Arity::Value("N");
    /// Meta: trace each parameter state separately for the finite-difference sample instead
    /// of the fused single trace (for comparison; with `var=zero`, since two traces cannot
    /// split their pixels for the centred variance estimate).
    fd_two_trace: bool = false, Arity::Switch;
    /// Coarse to fine: the iterations after which every grid parameter (a medium's
    /// density or emission) doubles its voxels along each axis, e.g. `100,200` (in TOML
    /// `[100, 200]`); θ and the optimiser's state are resampled trilinearly and carried on.
    upsample: Upsample = Upsample::default(), Arity::Value("ITERATIONS");
}

/// The iterations of the `upsample` setting, strictly increasing, each at least 1.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Upsample(pub Vec<u32>);

impl Upsample {
    fn check(&self) -> Result<(), String> {
        if self.0.first() == Some(&0) {
            return Err("an upsampling comes after an iteration: the first is at least 1".into());
        }
        match self.0.windows(2).find(|w| w[0] >= w[1]) {
            Some(w) => Err(format!("{} then {}: the iterations must increase", w[0], w[1])),
            None => Ok(()),
        }
    }
}

impl FromStr for Upsample {
    type Err = String;

    /// `100,200`, `[100, 200]` or `100 200`; empty for none.
    fn from_str(s: &str) -> Result<Self, String> {
        let inner = s.trim().trim_start_matches('[').trim_end_matches(']');
        let its = inner
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| t.parse::<u32>().map_err(|e| format!("'{t}': {e}")))
            .collect::<Result<Vec<_>, _>>()?;
        let u = Upsample(its);
        u.check()?;
        Ok(u)
    }
}

impl fmt::Display for Upsample {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        let its: Vec<String> = self.0.iter().map(u32::to_string).collect();
        f.write_str(&its.join(","))
    }
}

/// A bad setting: its key (as in TOML) and what is wrong.
#[derive(Clone, Debug, PartialEq)]
pub struct Invalid {
    pub key: &'static str,
    pub message: String,
}

impl Invalid {
    /// The key as a command-line flag: `--fd-spp`.
    pub fn flag(&self) -> String {
        format!("--{}", self.key.replace('_', "-"))
    }
}

impl Settings {
    /// Checks the range of every value this layer sets: counts at least 1, rates and budgets
    /// positive and finite. The only check of settings: the command line, the scene and job
    /// files all call it, each naming the key its own way.
    pub fn validate(&self) -> Result<(), Invalid> {
        let bad = |key, message: String| Err(Invalid { key, message });
        for (key, v) in [
            ("iterations", self.iterations),
            ("spp", self.spp),
            ("fd_spp", self.fd_spp),
            ("fd_stride", self.fd_stride),
            ("primal_spp", self.primal_spp),
            ("target_spp", self.target_spp),
            ("checkpoint_every", self.checkpoint_every),
        ] {
            if v == Some(0) {
                return bad(key, "must be at least 1".into());
            }
        }
        if let Some(Err(message)) = self.upsample.as_ref().map(Upsample::check) {
            return bad("upsample", message);
        }
        for (key, v) in [("lr", self.lr), ("time_budget", self.time_budget)] {
            // A NaN budget would never be reached and a negative one ends before the first step.
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return bad(key, format!("{v} is not positive and finite"));
            }
        }
        Ok(())
    }

    /// `self` with `over` on top, by the rules of the module documentation.
    pub fn then(&self, over: &Settings) -> Settings {
        let mut merged = self.overlay(over);
        if over.time_budget.is_some() && over.iterations.is_none() {
            merged.iterations = None;
        }
        merged
    }

    /// The run's settings: `scene` (its `[optimise]` table) with `over` (everything given
    /// outside the scene, already layered) on top, defaults below.
    pub fn resolve(scene: &Settings, over: &Settings) -> RunSettings {
        let all = scene.then(over);
        let mut run = all.fill(over.lr.is_some());
        if all.time_budget.is_some() && all.iterations.is_none() {
            run.iterations = None;
        }
        run
    }
}

impl RunSettings {
    /// The optimiser of the run: the spec's, with the settings' schedule when one is given
    /// and a cosine without a horizon decaying over the run's iterations (a run with a time
    /// budget alone must give the horizon).
    pub fn optimiser(&self) -> Result<Optimiser, Invalid> {
        let mut opt = self.optimiser.optimiser;
        if let Some(s) = self.schedule {
            *opt.schedule_mut() = s;
        }
        let s = opt.schedule();
        if s.decay == crate::optim::Decay::Cosine && s.horizon == 0 {
            let Some(n) = self.iterations else {
                return Err(Invalid { key: "schedule", message: "a cosine schedule of a run with a time budget alone needs horizon=N".into() });
            };
            return Ok(opt.resolve(n));
        }
        Ok(opt)
    }

    /// Whether the run is over after `iteration` iterations and `time_s` seconds: its
    /// iterations done, or its time budget reached, or too near to start another iteration
    /// of the mean length so far (so that a budget is overrun by less than an iteration,
    /// beyond the first).
    pub fn done(&self, iteration: u32, time_s: f64) -> bool {
        let per_iteration = if iteration > 0 { time_s / f64::from(iteration) } else { 0.0 };
        self.iterations.is_some_and(|n| iteration >= n) || self.time_budget.is_some_and(|b| time_s >= b || time_s + per_iteration > b)
    }
}

impl Serialize for Spec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.label)
    }
}

impl<'de> Deserialize<'de> for Spec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        text.parse().map_err(de::Error::custom)
    }
}

/// A TOML table that holds the run settings beside keys of its own (the scene's
/// `[optimise]`, a job file, a job entry). serde's `flatten` would lose toml's line
/// numbers and could not reject unknown keys; [`deserialize_table`] keeps both.
pub trait SettingsTable: Default {
    /// The table's own keys; a key that is both (a job file's `spp`) is its own.
    const OWN_KEYS: &'static [&'static str];
    /// Reads the value of own key `key` from `map`.
    fn read_own<'de, A: MapAccess<'de>>(&mut self, key: &'static str, map: &mut A) -> Result<(), A::Error>;
    fn settings_mut(&mut self) -> &mut Settings;
    /// Checks what a table must have (required keys) once every key is read.
    fn finish<E: de::Error>(self) -> Result<Self, E> {
        Ok(self)
    }
}

/// A key of a [`SettingsTable`]: one of its own or a setting, else an unknown-field error
/// (which toml places at the key).
struct KeySeed<'a> {
    own: &'static [&'static str],
    expected: &'a str,
}

impl<'de> DeserializeSeed<'de> for KeySeed<'_> {
    type Value = &'static str;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        d.deserialize_str(self)
    }
}

impl<'de> Visitor<'de> for KeySeed<'_> {
    type Value = &'static str;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a key")
    }
    fn visit_str<E: de::Error>(self, v: &str) -> Result<Self::Value, E> {
        self.own
            .iter()
            .chain(Settings::KEYS)
            .find(|k| **k == v)
            .copied()
            .ok_or_else(|| E::custom(format!("unknown field `{v}`, expected one of {}", self.expected)))
    }
}

/// Deserializes a [`SettingsTable`] (call it from the table's `Deserialize`).
pub fn deserialize_table<'de, D: Deserializer<'de>, T: SettingsTable>(d: D) -> Result<T, D::Error> {
    struct TableVisitor<T>(std::marker::PhantomData<T>);
    impl<'de, T: SettingsTable> Visitor<'de> for TableVisitor<T> {
        type Value = T;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("a table")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<T, A::Error> {
            let expected = T::OWN_KEYS.iter().chain(Settings::KEYS).map(|k| format!("`{k}`")).collect::<Vec<_>>().join(", ");
            let mut table = T::default();
            while let Some(key) = map.next_key_seed(KeySeed { own: T::OWN_KEYS, expected: &expected })? {
                if T::OWN_KEYS.contains(&key) {
                    table.read_own(key, &mut map)?;
                } else {
                    table.settings_mut().read_value(key, &mut map)?;
                }
            }
            table.finish()
        }
    }
    d.deserialize_map(TableVisitor(std::marker::PhantomData))
}

/// The scene's `[optimise]` table: the scene's layer of settings and its
/// `[[optimise.params]]` (of the scene file's type `P`).
#[derive(Debug)]
pub struct OptimiseTable<P> {
    pub settings: Settings,
    pub params: Vec<P>,
}

impl<P> Default for OptimiseTable<P> {
    fn default() -> Self {
        Self { settings: Settings::default(), params: Vec::new() }
    }
}

impl<P: for<'de> Deserialize<'de>> SettingsTable for OptimiseTable<P> {
    const OWN_KEYS: &'static [&'static str] = &["params"];
    fn read_own<'de, A: MapAccess<'de>>(&mut self, _key: &'static str, map: &mut A) -> Result<(), A::Error> {
        self.params = map.next_value()?;
        Ok(())
    }
    fn settings_mut(&mut self) -> &mut Settings {
        &mut self.settings
    }
}

impl<'de, P: for<'a> Deserialize<'a>> Deserialize<'de> for OptimiseTable<P> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        deserialize_table(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layer(text: &str) -> Settings {
        toml::from_str(text).unwrap()
    }

    #[test]
    fn layers_resolve_with_defaults_and_the_budget_rule() {
        let scene = layer("iterations = 200\nspp = 3\nlr = 0.1");
        let run = Settings::resolve(&scene, &Settings::default());
        assert_eq!((run.iterations, run.spp, run.lr, run.fd_spp, run.fd_stride), (Some(200), 3, 0.1, 1, 1));
        assert!(!run.lr_replaces_param_rates);
        // A budget from above drops the scene's iteration count; with its own count it keeps both.
        let budget = layer("time_budget = 2.5");
        assert_eq!(Settings::resolve(&scene, &budget).iterations, None);
        let both = layer("time_budget = 2.5\niterations = 7");
        assert_eq!(Settings::resolve(&scene, &both).iterations, Some(7));
        // A scene with a budget alone runs for the budget; without either, 500 iterations.
        assert_eq!(Settings::resolve(&budget, &Settings::default()).iterations, None);
        assert_eq!(Settings::resolve(&Settings::default(), &Settings::default()).iterations, Some(500));
        // A rate from outside the scene replaces the per-parameter rates.
        assert!(Settings::resolve(&scene, &layer("lr = 0.5")).lr_replaces_param_rates);
    }

    #[test]
    fn a_time_budget_starts_no_iteration_that_would_end_past_it() {
        let run = Settings::resolve(&layer("time_budget = 10"), &Settings::default());
        assert!(!run.done(0, 0.0));
        assert!(!run.done(4, 7.9), "8 s for 4 iterations: the fifth ends at 9.9");
        assert!(run.done(4, 8.1), "the fifth would end at 10.1");
        assert!(run.done(1, 49.0), "an overrun first iteration ends the run");
        let counted = Settings::resolve(&layer("iterations = 3"), &Settings::default());
        assert!(!counted.done(2, 1e9) && counted.done(3, 0.0));
    }

    #[test]
    fn seeds_are_u64_and_hashed_down_explicitly() {
        let s = layer("seed = 4294967296");
        assert_eq!(s.seed, Some(1 << 32));
        assert_eq!(gpu_seed(7), 7, "small seeds are used as they are");
        assert_ne!(gpu_seed(1 << 32), gpu_seed(0), "high bits are not dropped");
        assert_ne!(gpu_seed((1 << 32) + 5), gpu_seed(5));
    }

    #[test]
    fn one_validate_names_the_key() {
        for (text, key) in [
            ("spp = 0", "spp"),
            ("checkpoint_every = 0", "checkpoint_every"),
            ("lr = -1", "lr"),
            ("time_budget = nan", "time_budget"),
            ("iterations = 0", "iterations"),
            ("fd_stride = 0", "fd_stride"),
        ] {
            assert_eq!(layer(text).validate().unwrap_err().key, key, "{text}");
        }
        assert!(layer("spp = 1\nlr = 0.5\noptimiser = 'adam@beta1=0.5'\nloss = 'l1'").validate().is_ok());
        assert_eq!(Invalid { key: "fd_spp", message: String::new() }.flag(), "--fd-spp");
        let err = toml::from_str::<Settings>("spp = 1\nsppp = 2").unwrap_err().to_string();
        assert!(err.contains("sppp"), "{err}");
        let err = toml::from_str::<Settings>("optimiser = 'sgd'").unwrap_err().to_string();
        assert!(err.contains("unknown optimiser 'sgd'"), "{err}");
    }

    #[test]
    fn fields_declare_every_key_and_set_parses_their_text() {
        let keys: Vec<&str> = Settings::FIELDS.iter().map(|f| f.key).collect();
        assert_eq!(keys, Settings::KEYS);
        assert!(Settings::FIELDS.iter().all(|f| !f.help.trim().is_empty()), "every setting has help text");
        let spp = Settings::FIELDS.iter().find(|f| f.key == "fd_spp").unwrap();
        assert_eq!((spp.flag(), spp.arity), ("--fd-spp".to_string(), Arity::Value("N")));
        let mut s = Settings::default();
        for (key, text) in [("spp", "3"), ("lr", "0.5"), ("optimiser", "adam@beta1=0.5"), ("loss", "l1"), ("fd_two_trace", "true"), ("schedule", "cosine")] {
            s.set(key, text).unwrap_or_else(|e| panic!("{key} = {text}: {}", e.message));
        }
        assert_eq!(s, layer("spp = 3\nlr = 0.5\noptimiser = 'adam@beta1=0.5'\nloss = 'l1'\nfd_two_trace = true\nschedule = 'cosine'"));
        let e = s.set("spp", "three").unwrap_err();
        assert_eq!(e.key, "spp");
        assert!(e.message.contains("'three'"), "{}", e.message);
        assert!(s.set("optimiser", "sgd").unwrap_err().message.contains("unknown optimiser 'sgd'"));
        assert!(s.set("sppp", "1").unwrap_err().message.contains("unknown setting 'sppp'"));
    }

    #[test]
    fn changes_name_each_setting() {
        let a = Settings::resolve(&layer("spp = 2"), &Settings::default());
        let b = Settings::resolve(&layer("spp = 4\nseed = 3"), &Settings::default());
        assert_eq!(a.changes(&b), ["spp: 2 -> 4", "seed: 0 -> 3"]);
        assert!(a.changes(&a).is_empty());
    }

    #[test]
    fn tables_keep_line_numbers() {
        #[derive(Deserialize)]
        struct File {
            #[allow(dead_code)]
            t: OptimiseTable<u32>,
        }
        let ok: File = toml::from_str("[t]\nparams = [1, 2]\nspp = 3\n").unwrap();
        assert_eq!((ok.t.params, ok.t.settings.spp), (vec![1, 2], Some(3)));
        let unknown = toml::from_str::<File>("[t]\nparams = []\nsppp = 3\n").err().unwrap();
        assert!(unknown.to_string().contains("line 3, column 1"), "{unknown}");
        assert!(unknown.message().contains("unknown field `sppp`"), "{unknown}");
        let wrong_type = toml::from_str::<File>("[t]\nspp = 'x'\n").err().unwrap();
        assert!(wrong_type.to_string().contains("line 2, column 7"), "{wrong_type}");
    }
}
