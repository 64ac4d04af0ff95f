//! A posterior sample in SI units: the chains of a calibration as the
//! outputs name them, and the draws that predictions integrate.
//!
//! The same type comes from the sampler's chains in memory and from
//! `chains.parquet` read back, so every later stage (bands, leave-one-out,
//! comparisons, figures) treats both alike.

use super::layout::Layout;
use super::likelihood::LaneParams;
use super::parameters::ParameterModel;
use crate::data::RunData;
use crate::laws::bodner_partom::{params_of, values_of};
use crate::laws::{LawKind, LawValues};
use crate::model::{FieldLaw, Params};
use crate::noise::NoiseValues;
use crate::sampler::{Chains, Diagnostics, ParameterDiagnostics};

/// One posterior draw as a run sees it: the law's parameters, the model
/// terms (0 where off) and the noise parameters of that run (SI, in the
/// noise model's order).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Draw {
    /// The damper law.
    pub law: LawKind,
    /// Its parameters at the run's (nominal) current.
    pub values: LawValues,
    /// A law's draw: how the parameters follow the current, and the coil's
    /// lag (s), for a run whose current varies.
    pub field: Option<(FieldLaw, f64)>,
    pub spring_n_per_m: f64,
    pub offset_n: f64,
    pub noise: NoiseValues,
}

impl Draw {
    /// A draw of the B-P law alone: no model terms, noise `noise`.
    pub fn of_law(params: Params, noise: NoiseValues) -> Self {
        Draw::of(LawKind::BodnerPartom, values_of(&params), noise)
    }

    /// A draw of `law` alone: no model terms, noise `noise`.
    pub fn of(law: LawKind, values: LawValues, noise: NoiseValues) -> Self {
        Draw { law, values, field: None, spring_n_per_m: 0.0, offset_n: 0.0, noise }
    }

    /// The B-P parameters of a draw of the B-P law.
    pub fn params(&self) -> Params {
        params_of(&self.values)
    }

    /// The bound of the law's tangent stiffness at the draw's parameters
    /// (for the B-P law its G at the run's nominal current).
    pub fn stiffness(&self, run: &RunData) -> f64 {
        self.law.law().stiffness_bound(&self.values, run)
    }

    /// The parameters of up to `LANES` draws (the last repeated) along `run`.
    pub fn lanes(draws: &[Draw], run: &RunData) -> LaneParams {
        let at = |lane: usize| &draws[lane.min(draws.len() - 1)];
        match (run.current.is_some(), draws.iter().all(|d| d.field.is_some())) {
            (true, true) => LaneParams::Along {
                laws: std::array::from_fn(|lane| at(lane).field.expect("a law").0),
                lags_s: std::array::from_fn(|lane| at(lane).field.expect("a law").1),
            },
            _ => LaneParams::Fixed {
                law: draws[0].law,
                values: std::array::from_fn(|lane| at(lane).values),
            },
        }
    }

    /// G along `run`, the bound of the law's tangent stiffness
    /// ([`LaneParams::g_bound`]).
    pub fn g_bound(&self, run: &RunData) -> f64 {
        Draw::lanes(std::slice::from_ref(self), run).g_bound(run)[0]
    }
}

/// Every step of every walker in SI units, with the layout that names them.
#[derive(Clone, Debug)]
pub struct PosteriorSample {
    pub layout: Layout,
    pub model: ParameterModel,
    /// Positions in SI units (θ, σ, ρ), `[step][chain][coordinate]`.
    pub chains: Chains,
    /// The nominal coil current of each calibrated run (A), in the
    /// layout's order of runs; empty where not known (a folder written
    /// before it was recorded). A run the posterior did not see takes its
    /// noise from the runs nearest in current ([`Self::draw_without`]).
    pub run_currents: Vec<f64>,
}

impl PosteriorSample {
    /// The sample of sampler chains in unconstrained coordinates, of runs
    /// at `run_currents`.
    pub fn from_coordinates(
        layout: &Layout,
        model: ParameterModel,
        chains: &Chains,
        run_currents: Vec<f64>,
    ) -> Self {
        PosteriorSample {
            layout: layout.clone(),
            model,
            chains: chains.map_points(|x| layout.to_si(x)),
            run_currents,
        }
    }

    /// Diagnostics of every coordinate in SI units after `burn_in` steps.
    pub fn diagnostics(&self, burn_in: usize) -> Diagnostics {
        Diagnostics::compute(&self.chains, burn_in)
    }

    /// The values of coordinate `name` at `positions`.
    pub fn values(&self, name: &str, positions: &[(usize, usize)]) -> Option<Vec<f64>> {
        let i = self.layout.index(name)?;
        Some(positions.iter().map(|&(s, c)| self.chains.at(s, c, i)).collect())
    }

    /// The B-P parameters at one position, at a coil current (a B-P
    /// calibration's).
    pub fn params_at(&self, step: usize, chain: usize, current_a: f64) -> Params {
        let x = self.chains.point(step, chain);
        self.model.params(&x[self.layout.theta.clone()], current_a)
    }

    /// The law's parameters at one position, at a coil current.
    pub fn values_at(&self, step: usize, chain: usize, current_a: f64) -> LawValues {
        let x = self.chains.point(step, chain);
        self.model.values(&x[self.layout.theta.clone()], current_a)
    }

    /// A law's field law and coil lag at one position; `None` for one
    /// parameter set.
    pub fn field_at(&self, step: usize, chain: usize) -> Option<(FieldLaw, f64)> {
        self.model.field(&self.chains.point(step, chain)[self.layout.theta.clone()])
    }

    /// The draw at one position for run `run` at `current_a`. A run the
    /// posterior did not see has no noise of its own: it gets that of the
    /// runs it saw, pooled ([`Self::draw_without`]).
    pub fn draw(&self, step: usize, chain: usize, run: &str, current_a: f64) -> Draw {
        let x = self.chains.point(step, chain);
        match self.layout.run_index(run) {
            Some(j) => {
                let (spring_n_per_m, offset_n) = self.layout.terms(x, j);
                Draw {
                    law: self.model.law(),
                    values: self.values_at(step, chain, current_a),
                    field: self.field_at(step, chain),
                    spring_n_per_m,
                    offset_n,
                    noise: self.layout.noise_values(x, j),
                }
            }
            None => self.draw_without(step, chain, run, current_a),
        }
    }

    /// The draw at one position for run `run` as if the posterior had not
    /// seen it: the noise of the other runs pooled (the root-mean-square
    /// σ, the mean ρ, …, as [`Layout::noise_at_current`] says) and their mean force
    /// offset.
    pub fn draw_without(&self, step: usize, chain: usize, run: &str, current_a: f64) -> Draw {
        let x = self.chains.point(step, chain);
        let l = &self.layout;
        let others: Vec<usize> = (0..l.runs.len()).filter(|&i| l.runs[i] != run).collect();
        let offsets: Vec<f64> = others.iter().map(|&i| l.terms(x, i).1).collect();
        Draw {
            law: self.model.law(),
            values: self.values_at(step, chain, current_a),
            field: self.field_at(step, chain),
            spring_n_per_m: l.terms(x, 0).0,
            offset_n: crate::noise::Pool::Mean.of(&offsets),
            noise: l.noise_at_current(x, &others, &self.run_currents, current_a),
        }
    }

    /// The draws at `positions` for one run.
    pub fn draws(&self, positions: &[(usize, usize)], run: &str, current_a: f64) -> Vec<Draw> {
        positions.iter().map(|&(s, c)| self.draw(s, c, run, current_a)).collect()
    }
}

/// One row of a posterior summary: a coordinate's name and its statistics.
#[derive(Clone, Debug, PartialEq)]
pub struct SummaryRow {
    pub parameter: String,
    pub stats: ParameterDiagnostics,
}

impl std::ops::Deref for SummaryRow {
    type Target = ParameterDiagnostics;
    fn deref(&self) -> &ParameterDiagnostics {
        &self.stats
    }
}

impl SummaryRow {
    /// The rows of `diagnostics`, named by `layout`.
    pub fn rows(layout: &Layout, diagnostics: &Diagnostics) -> Vec<SummaryRow> {
        layout
            .names
            .iter()
            .zip(&diagnostics.coordinates)
            .map(|(n, d)| SummaryRow { parameter: n.clone(), stats: d.clone() })
            .collect()
    }
}

/// Which draws of a posterior sample a stage takes: every `thin`-th step
/// from `burn_in` on, each chain. Every stage that uses posterior draws
/// (bands, pointwise terms, comparisons, figures, leave-one-out, studies)
/// picks them here.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Draws {
    pub burn_in: usize,
    pub thin: usize,
}

impl Draws {
    /// The draws after `burn_in`, thinned by ⌈τ⌉ steps (nearly independent;
    /// every step where τ is not known).
    pub fn after(burn_in: usize, tau: f64) -> Draws {
        let thin = if tau.is_finite() { tau.ceil().max(1.0) as usize } else { 1 };
        Draws { burn_in, thin }
    }

    /// `count` of them spread evenly over the steps and chains (all if
    /// fewer), each as `(step, chain)`.
    pub fn positions(self, chains: &Chains, count: usize) -> Vec<(usize, usize)> {
        let n = chains.chains();
        let all: Vec<(usize, usize)> = (self.burn_in..chains.steps())
            .step_by(self.thin.max(1))
            .flat_map(|s| (0..n).map(move |c| (s, c)))
            .collect();
        evenly_spaced(all.len(), count).into_iter().map(|i| all[i]).collect()
    }

    /// About `count` of them as whole steps (every chain at each, as
    /// ArviZ's chain × draw grid wants), evenly spaced from the burn-in to
    /// the last step and at least `thin` steps apart: at least one step.
    pub fn steps(self, chains: &Chains, count: usize) -> Vec<usize> {
        let steps = chains.steps();
        let available = steps.saturating_sub(self.burn_in).max(1);
        let per_chain =
            count.div_ceil(chains.chains().max(1)).min(available.div_ceil(self.thin.max(1))).max(1);
        evenly_spaced(available, per_chain)
            .into_iter()
            .map(|i| (self.burn_in + i).min(steps.saturating_sub(1)))
            .collect()
    }
}

/// Indices of `count` draws spread evenly over `available` (all of them if
/// there are fewer): deterministic thinning without randomness.
pub fn evenly_spaced(available: usize, count: usize) -> Vec<usize> {
    if count == 0 || available <= count {
        return (0..available).collect();
    }
    (0..count).map(|i| (i * available) / count + available / (2 * count)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::{NoiseKind, NoiseOptions};

    #[test]
    fn evenly_spaced_indices_cover_the_range() {
        assert_eq!(evenly_spaced(5, 10), vec![0, 1, 2, 3, 4]);
        assert_eq!(evenly_spaced(1000, 4), vec![125, 375, 625, 875]);
    }

    /// A seen run gets its own σ and ρ; an unseen one the RMS σ and mean ρ.
    #[test]
    fn draws_take_the_runs_own_noise_or_the_pooled_one() {
        let runs = vec!["a".to_string(), "b".to_string()];
        let ar1 = NoiseKind::Ar1.model(&NoiseOptions::default());
        let layout = Layout::new(
            &ParameterModel::PerCurrent,
            &runs,
            ar1.as_ref(),
            crate::posterior::Coordinates::Log,
            &Default::default(),
        );
        let mut point = Params::reference_1a().to_array().to_vec();
        point.extend([3.0, 4.0, 0.2, 0.6]);
        let chains = Chains {
            dim: 11,
            ensembles: 1,
            walkers: 1,
            positions: point,
            log_prob: vec![0.0],
            accepted: vec![false],
        };
        let sample = PosteriorSample {
            layout,
            model: ParameterModel::PerCurrent,
            chains,
            run_currents: Vec::new(),
        };
        let own = sample.draw(0, 0, "b", 1.0);
        assert_eq!((own.noise, own.offset_n), ([4.0, 0.6, 0.0, 0.0], 0.0));
        assert_eq!(own.params(), Params::reference_1a());
        let unseen = sample.draw(0, 0, "c", 1.0);
        assert!(
            (unseen.noise[0] - 12.5f64.sqrt()).abs() < 1e-12
                && (unseen.noise[1] - 0.4).abs() < 1e-12
        );
    }

    /// An unseen run's σ follows the current: its own current's runs
    /// pooled, linear between two calibrated currents, the nearest outside
    /// them; all runs pooled where the currents are not known.
    #[test]
    fn an_unseen_runs_noise_follows_the_current() {
        let runs: Vec<String> = ["a", "b", "c"].iter().map(|s| s.to_string()).collect();
        let gaussian = NoiseKind::Gaussian.model(&NoiseOptions::default());
        let layout = Layout::new(
            &ParameterModel::PerCurrent,
            &runs,
            gaussian.as_ref(),
            crate::posterior::Coordinates::Log,
            &Default::default(),
        );
        let mut point = Params::reference_1a().to_array().to_vec();
        point.extend([100.0, 100.0, 300.0]);
        let chains = Chains {
            dim: 10,
            ensembles: 1,
            walkers: 1,
            positions: point,
            log_prob: vec![0.0],
            accepted: vec![false],
        };
        let mut sample = PosteriorSample {
            layout,
            model: ParameterModel::PerCurrent,
            chains,
            run_currents: vec![0.25, 0.25, 1.0],
        };
        let sigma = |s: &PosteriorSample, current: f64| s.draw(0, 0, "new", current).noise[0];
        // 100 + (0.5 − 0.25) / (1 − 0.25) × (300 − 100)
        assert!((sigma(&sample, 0.5) - (100.0 + 200.0 / 3.0)).abs() < 1e-9);
        assert!((sigma(&sample, 0.25) - 100.0).abs() < 1e-9);
        assert!((sigma(&sample, 0.1) - 100.0).abs() < 1e-9);
        assert!((sigma(&sample, 1.5) - 300.0).abs() < 1e-9);
        // a run left out of the 1 A level leaves 0.25 A alone: its pool
        assert!((sample.draw_without(0, 0, "c", 1.0).noise[0] - 100.0).abs() < 1e-9);
        sample.run_currents.clear();
        assert!((sigma(&sample, 0.5) - (110_000.0f64 / 3.0).sqrt()).abs() < 1e-9);
    }
}
