//! The history of a sampler run: every position, log-density and
//! acceptance of every walker at every step.

use serde::{Deserialize, Serialize};

/// Every step of every walker: positions, log-densities and whether the
/// step's proposal was accepted. Walker index `w` of ensemble `e` is chain
/// `e * walkers + w`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chains {
    pub dim: usize,
    pub ensembles: usize,
    pub walkers: usize,
    /// Step-major: `[step][chain][coordinate]`.
    pub positions: Vec<f64>,
    /// `[step][chain]`.
    pub log_prob: Vec<f64>,
    /// `[step][chain]`.
    pub accepted: Vec<bool>,
}

impl Chains {
    pub fn chains(&self) -> usize {
        self.ensembles * self.walkers
    }

    pub fn steps(&self) -> usize {
        self.log_prob.len() / self.chains().max(1)
    }

    /// Coordinate `i` of chain `c` at `step`.
    pub fn at(&self, step: usize, chain: usize, i: usize) -> f64 {
        self.positions[(step * self.chains() + chain) * self.dim + i]
    }

    /// The position of chain `c` at `step`.
    pub fn point(&self, step: usize, chain: usize) -> &[f64] {
        let start = (step * self.chains() + chain) * self.dim;
        &self.positions[start..start + self.dim]
    }

    /// The same chains with every position mapped by `f` (to other
    /// coordinates, say), log-densities and acceptances kept.
    pub fn map_points(&self, f: impl Fn(&[f64]) -> Vec<f64>) -> Chains {
        let positions: Vec<f64> =
            self.positions.chunks_exact(self.dim.max(1)).flat_map(&f).collect();
        let dim =
            if self.log_prob.is_empty() { self.dim } else { positions.len() / self.log_prob.len() };
        Chains {
            dim,
            ensembles: self.ensembles,
            walkers: self.walkers,
            positions,
            log_prob: self.log_prob.clone(),
            accepted: self.accepted.clone(),
        }
    }

    /// The chains as they were after their first `steps` steps (the
    /// initial state counting as one).
    pub fn first_steps(&self, steps: usize) -> Chains {
        let n = steps.min(self.steps()) * self.chains();
        Chains {
            positions: self.positions[..n * self.dim].to_vec(),
            log_prob: self.log_prob[..n].to_vec(),
            accepted: self.accepted[..n].to_vec(),
            ..*self
        }
    }

    /// The trace of coordinate `i` of every chain from step `from` on:
    /// `[chain][step]`.
    pub fn traces(&self, i: usize, from: usize) -> Vec<Vec<f64>> {
        (0..self.chains())
            .map(|c| (from..self.steps()).map(|s| self.at(s, c, i)).collect())
            .collect()
    }

    /// The traces of an arbitrary function of the position.
    pub fn traces_of(&self, from: usize, f: impl Fn(&[f64]) -> f64) -> Vec<Vec<f64>> {
        let (d, nc) = (self.dim, self.chains());
        (0..nc)
            .map(|c| {
                (from..self.steps())
                    .map(|s| f(&self.positions[(s * nc + c) * d..(s * nc + c + 1) * d]))
                    .collect()
            })
            .collect()
    }

    /// Acceptance fraction of each chain over steps `from..`.
    pub fn acceptance(&self, from: usize) -> Vec<f64> {
        let nc = self.chains();
        let steps = self.steps().saturating_sub(from).max(1);
        (0..nc)
            .map(|c| {
                (from..self.steps()).filter(|&s| self.accepted[s * nc + c]).count() as f64
                    / steps as f64
            })
            .collect()
    }

    /// The last position of every chain, `[chain][coordinate]` flattened.
    pub fn last_positions(&self) -> &[f64] {
        let n = self.chains() * self.dim;
        &self.positions[self.positions.len() - n..]
    }

    pub fn last_log_prob(&self) -> &[f64] {
        let n = self.chains();
        &self.log_prob[self.log_prob.len() - n..]
    }
}
