//! Run settings given outside the scene file (command-line flags of `compare`, the entries
//! of a `batch` job file) and how they override the scene's `[optimise]` table.
//!
//! The rules are those of `vkinverse optimise`: a time budget without an iteration count
//! runs for the budget alone; a learning rate applies to every parameter, replacing the
//! per-parameter rates of the scene.

use crate::optim::Optimiser;
use crate::optimise::Settings;
use crate::scene::Scene;
use serde::{Deserialize, Serialize};

/// Values that replace the scene's; `None` keeps the scene's value.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Overrides {
    pub iterations: Option<u32>,
    pub time_budget: Option<f64>,
    pub spp: Option<u32>,
    pub fd_spp: Option<u32>,
    pub primal_spp: Option<u32>,
    pub lr: Option<f32>,
    pub seed: Option<u32>,
    pub checkpoint_every: Option<u32>,
}

impl Overrides {
    /// `self` with every value that `other` sets replaced by `other`'s.
    pub fn then(&self, other: &Overrides) -> Overrides {
        Overrides {
            iterations: other.iterations.or(self.iterations),
            time_budget: other.time_budget.or(self.time_budget),
            spp: other.spp.or(self.spp),
            fd_spp: other.fd_spp.or(self.fd_spp),
            primal_spp: other.primal_spp.or(self.primal_spp),
            lr: other.lr.or(self.lr),
            seed: other.seed.or(self.seed),
            checkpoint_every: other.checkpoint_every.or(self.checkpoint_every),
        }
    }

    /// Checks the values that have a valid range, naming the key (as in a job file) of the
    /// first bad one. Nothing here needs the scene, so a job list is checked before any run.
    pub fn check(&self) -> Result<(), String> {
        for (key, v) in [("spp", self.spp), ("fd_spp", self.fd_spp), ("primal_spp", self.primal_spp)] {
            if v == Some(0) {
                return Err(format!("{key} must be at least 1"));
            }
        }
        for (key, v) in [("lr", self.lr.map(f64::from)), ("time_budget", self.time_budget)] {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(format!("{key} = {v} must be positive and finite"));
            }
        }
        Ok(())
    }

    /// The scene to run (with the learning rate applied) and its settings for `optimiser`
    /// (the scene's own when `None`).
    pub fn apply(&self, scene: &Scene, optimiser: Option<Optimiser>) -> (Scene, Settings) {
        let mut st = Settings::from_scene(scene);
        if let Some(o) = optimiser {
            st.optimiser = o;
        }
        if let Some(t) = self.time_budget {
            st.time_budget = Some(t);
            if self.iterations.is_none() {
                st.iterations = 0;
            }
        }
        st.iterations = self.iterations.unwrap_or(st.iterations);
        st.spp = self.spp.unwrap_or(st.spp);
        st.fd_spp = self.fd_spp.unwrap_or(st.fd_spp);
        st.primal_spp = self.primal_spp.unwrap_or(st.primal_spp);
        st.lr = self.lr.unwrap_or(st.lr);
        st.seed = self.seed.unwrap_or(st.seed);
        st.checkpoint_every = self.checkpoint_every.unwrap_or(st.checkpoint_every);
        let mut scene = scene.clone();
        if let Some(lr) = self.lr {
            // The parameter layout reads learning rates from the scene, not the settings.
            scene.optimise.lr = lr;
            for p in &mut scene.optimise.params {
                p.lr = None;
            }
        }
        (scene, st)
    }
}
