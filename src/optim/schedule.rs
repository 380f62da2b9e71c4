//! Learning-rate schedules: the factor by which step t (from 1) scales the learning rate, a
//! pure function of t that `glsl/lib/optim.glsl` (`schedule_factor`) evaluates the same way
//! on the GPU, so a recorded iteration needs no new push constants.
//!
//! factor(t) = warm-up(t) · decay(t):
//! - warm-up: t / warmup for t < warmup (a linear ramp that ends at 1), else 1;
//! - decay: `constant` 1; `cosine` floor + (1 − floor)·½(1 + cos(π·min(t, horizon)/horizon))
//!   (from 1 at t = 0 to `floor` at the horizon, then flat); `step` gamma^⌊t / every⌋.
//!
//! A cosine horizon of 0 means "the run's iteration count", filled in by [`Schedule::resolve`]
//! when the run starts; a run with only a time budget needs an explicit horizon.

use super::OptimError;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;
use std::str::FromStr;

/// How the learning rate decays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Decay {
    #[default]
    Constant,
    Cosine,
    Step,
}

impl Decay {
    /// The kernels' number for it (`SCHEDULE_*`, src/constants.rs).
    pub fn code(self) -> u32 {
        use crate::constants::*;
        match self {
            Decay::Constant => SCHEDULE_CONSTANT,
            Decay::Cosine => SCHEDULE_COSINE,
            Decay::Step => SCHEDULE_STEP,
        }
    }
}

impl FromStr for Decay {
    type Err = OptimError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "constant" => Ok(Decay::Constant),
            "cosine" => Ok(Decay::Cosine),
            "step" => Ok(Decay::Step),
            _ => Err(OptimError::BadHyper(format!("schedule '{s}' (expected constant, cosine or step)"))),
        }
    }
}

impl fmt::Display for Decay {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Decay::Constant => "constant",
            Decay::Cosine => "cosine",
            Decay::Step => "step",
        })
    }
}

/// A learning-rate schedule; the default is constant with no warm-up. Written
/// `DECAY[@KEY=VALUE]...` (`cosine@floor=0.05@warmup=10`) in settings and job files.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Schedule {
    pub decay: Decay,
    /// Iterations of the linear warm-up (0: none).
    pub warmup: u32,
    /// Cosine: the iteration at which the factor reaches `floor` (0: the run's length).
    pub horizon: u32,
    /// Cosine: the final factor, in [0, 1].
    pub floor: f64,
    /// Step: iterations between decays.
    pub every: u32,
    /// Step: the factor of each decay, in (0, 1].
    pub gamma: f64,
}

impl Default for Schedule {
    fn default() -> Self {
        Schedule { decay: Decay::Constant, warmup: 0, horizon: 0, floor: 0.0, every: 100, gamma: 0.5 }
    }
}

impl Schedule {
    /// The schedule with a cosine horizon of 0 replaced by the run's `iterations`.
    pub fn resolve(mut self, iterations: u32) -> Self {
        if self.horizon == 0 {
            self.horizon = iterations;
        }
        self
    }

    /// Checks the values, naming the first bad one.
    pub fn validate(&self) -> Result<(), OptimError> {
        if !(0.0..=1.0).contains(&self.floor) {
            return Err(OptimError::BadHyper(format!("floor = {} is outside [0, 1]", self.floor)));
        }
        if !(self.gamma > 0.0 && self.gamma <= 1.0) {
            return Err(OptimError::BadHyper(format!("gamma = {} is outside (0, 1]", self.gamma)));
        }
        if self.decay == Decay::Step && self.every == 0 {
            return Err(OptimError::BadHyper("every = 0: a step schedule needs a positive interval".into()));
        }
        Ok(())
    }

    /// The factor of step t (t ≥ 1) in f64: the reference of the kernels' `schedule_factor`.
    pub fn factor(&self, t: u32) -> f64 {
        let warm = if t < self.warmup { t as f64 / self.warmup as f64 } else { 1.0 };
        let decay = match self.decay {
            Decay::Constant => 1.0,
            Decay::Cosine if self.horizon == 0 => 1.0,
            Decay::Cosine => {
                let x = t.min(self.horizon) as f64 / self.horizon as f64;
                self.floor + (1.0 - self.floor) * 0.5 * (1.0 + (std::f64::consts::PI * x).cos())
            }
            Decay::Step => self.gamma.powi((t / self.every.max(1)) as i32),
        };
        warm * decay
    }

    /// Sets one spec key (`schedule`, `warmup`, `horizon`, `floor`, `every`, `gamma`);
    /// `Ok(false)` when the key is not a schedule key.
    pub fn set(&mut self, key: &str, value: &str) -> Result<bool, OptimError> {
        let bad = |what: &str| OptimError::BadHyper(format!("{key} = '{value}' is not {what}"));
        let count = || value.parse::<u32>().map_err(|_| bad("a non-negative integer"));
        let real = || value.parse::<f64>().map_err(|_| bad("a number"));
        match key {
            "schedule" => self.decay = value.parse()?,
            "warmup" => self.warmup = count()?,
            "horizon" => self.horizon = count()?,
            "every" => self.every = count()?,
            "floor" => self.floor = real()?,
            "gamma" => self.gamma = real()?,
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// The spec keys of a schedule, for error messages.
    pub const KEYS: &'static str = "schedule, warmup, horizon, floor, every, gamma";
}

/// Parses `DECAY[@KEY=VALUE]...` (the keys of [`Schedule::set`] but `schedule`).
impl FromStr for Schedule {
    type Err = OptimError;
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let mut parts = text.trim().split('@');
        let mut s = Schedule { decay: parts.next().unwrap_or_default().parse()?, ..Schedule::default() };
        for part in parts {
            let (key, value) = part.split_once('=').ok_or_else(|| OptimError::BadHyper(format!("schedule '{text}': '{part}' is not KEY=VALUE")))?;
            if key == "schedule" || !s.set(key.trim(), value.trim())? {
                return Err(OptimError::BadHyper(format!("schedule '{text}': unknown key '{key}' (expected warmup, horizon, floor, every or gamma)")));
            }
        }
        s.validate()?;
        Ok(s)
    }
}

/// The canonical text: the decay and the keys it uses, and the warm-up when there is one.
impl fmt::Display for Schedule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.decay)?;
        match self.decay {
            Decay::Constant => {}
            Decay::Cosine => write!(f, "@horizon={}@floor={}", self.horizon, self.floor)?,
            Decay::Step => write!(f, "@every={}@gamma={}", self.every, self.gamma)?,
        }
        if self.warmup > 0 {
            write!(f, "@warmup={}", self.warmup)?;
        }
        Ok(())
    }
}

impl Serialize for Schedule {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for Schedule {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn factors() {
        let c = Schedule::default();
        assert!((1..1000).all(|t| c.factor(t) == 1.0));
        let w = Schedule { warmup: 10, ..c };
        assert_eq!((w.factor(1), w.factor(5), w.factor(10), w.factor(500)), (0.1, 0.5, 1.0, 1.0));
        let cos = Schedule { decay: Decay::Cosine, horizon: 100, floor: 0.1, ..c };
        assert!((cos.factor(50) - 0.55).abs() < 1e-12);
        assert!((cos.factor(100) - 0.1).abs() < 1e-12 && cos.factor(1000) == cos.factor(100));
        assert!((1..100).all(|t| cos.factor(t + 1) < cos.factor(t)));
        let st = Schedule { decay: Decay::Step, every: 50, gamma: 0.5, ..c };
        assert_eq!((st.factor(49), st.factor(50), st.factor(149), st.factor(150)), (1.0, 0.5, 0.25, 0.125));
        let open = Schedule { decay: Decay::Cosine, ..c };
        assert_eq!(open.factor(7), 1.0);
        assert_eq!(open.resolve(300).horizon, 300);
        assert_eq!(cos.resolve(300).horizon, 100);
    }

    #[test]
    fn keys_and_validation() {
        let mut s = Schedule::default();
        assert!(s.set("schedule", "cosine").unwrap() && s.set("warmup", "5").unwrap());
        assert!(!s.set("lr", "1").unwrap());
        assert_eq!((s.decay, s.warmup), (Decay::Cosine, 5));
        assert!(s.set("schedule", "linear").unwrap_err().to_string().contains("expected constant, cosine or step"));
        assert!(s.set("warmup", "-1").unwrap_err().to_string().contains("non-negative integer"));
        assert!(Schedule { floor: 1.5, ..s }.validate().is_err());
        assert!(Schedule { gamma: 0.0, ..s }.validate().is_err());
        assert!(Schedule { decay: Decay::Step, every: 0, ..s }.validate().is_err());
        let text: Schedule = "cosine@floor=0.05@warmup=10".parse().unwrap();
        assert_eq!((text.decay, text.floor, text.warmup, text.horizon), (Decay::Cosine, 0.05, 10, 0));
        assert_eq!(text.to_string().parse::<Schedule>().unwrap(), text);
        assert_eq!("step@every=50".parse::<Schedule>().unwrap().to_string(), "step@every=50@gamma=0.5");
        assert!("cosine@lr=2".parse::<Schedule>().unwrap_err().to_string().contains("unknown key 'lr'"));
        assert!("cosine@floor".parse::<Schedule>().unwrap_err().to_string().contains("not KEY=VALUE"));
        assert!("linear".parse::<Schedule>().is_err());
    }
}
