//! The between-run layer: the runs of one damper as draws from a population
//! of tests, so that a calibration can say what **a new test** of the
//! damper would give, not only what these records give.
//!
//! Each run i, at coil current c(i), has its own parameters z_i: the damper
//! law's parameters in the calibration's own coordinates (ln θ; for the
//! B-P law by default the
//! hardening coordinates ln G, ln(R0 + D1), ln Z*, ln(D1/R0), ln m1, ln m2,
//! ln n, with Z* the drag stress after the median plastic work of the runs
//! fitted: combinations a record determines nearly independently of each
//! other), the model terms where they are on, and the noise model's
//! coordinates of its noise (ln σ, …). They are drawn from a population
//!
//!   z_i ~ N(μ_c(i), Σ),
//!
//! with a centre μ_c per current (flat prior) and one between-test
//! covariance Σ shared by the currents: how much the excitation (stroke,
//! frequency) moves the parameters, learned from every run at every
//! current. Σ has the prior of Huang & Wand (2013),
//! Σ | a ~ IW(ν + d − 1, 2ν diag(1/a)), a_k ~ IG(½, 1/A_k²), ν = 2: each
//! sd half-t(2, A_k) — A_k = 1 for a logarithm (one e-fold between tests),
//! the prior sd for a term in newtons — and each correlation uniform on
//! (−1, 1). A new test at current c draws z_new ~ N(μ_c, Σ).
//!
//! It is fitted in two stages (as in meta-analysis; Lunn, Barrett,
//! Sweeting & Richardson 2013): each run calibrated alone under its prior p₀
//! gives draws of p(z_i | y_i) ∝ L_i(z_i) p₀(z_i). In the layer's
//! coordinates, where a run's posterior is close to normal, each run's
//! likelihood is taken as the normal that its draws' mean and covariance
//! give once p₀ is divided out (p₀'s gradient and curvature at that mean,
//! by finite differences: a direction the record does not determine, where
//! the posterior is the prior's, gets no information from the run). A Gibbs
//! sampler then draws each z_i, the centres, Σ and the prior's auxiliary
//! scales from their conditionals (normal, inverse Wishart by Bartlett's
//! decomposition, inverse gamma): continuous draws, which mix where the
//! tests agree as well as where they disagree. No log-density of the
//! damper law is computed: the runs' own chains carry their likelihoods.

//!
//! One concept, four files: the run's likelihood as the layer takes it
//! ([`likelihood`]), the centres' curve in the current ([`curve`]), the
//! Gibbs sampler ([`gibbs`]), and each run predicted as a new test by the
//! layer fitted without it ([`leave_out`]); this file fits the layer to
//! calibrations and draws new tests from it.

pub mod curve;
pub mod gibbs;
pub mod leave_out;
pub mod likelihood;

use rayon::prelude::*;

use crate::calibrate::Calibration;
use crate::compare::CurrentKind;
use crate::data::{same_current, RunData};
use crate::error::{Error, Result};
use crate::laws::{LawKind, LawValues, MAX_LAW_PARAMETERS};
use crate::noise::{NoiseModel, NoiseValues, Transform, MAX_PARAMETERS};
use crate::posterior::layout::Hardening;
use crate::posterior::{evenly_spaced, Coordinates, Draw, Layout, ModelTerms, Prior};
use crate::sampler::{quantile_sorted, Chains, Diagnostics};
use rand::RngExt;
use rand_distr::StandardNormal;

pub use curve::{current_coordinate, CurrentCurve, CURRENT_SCALE_A};
use gibbs::Chain;
pub use gibbs::{gibbs, GibbsSettings, LayerDraw, CHAINS, MAX_BLOCKS, PRIOR_DF};
pub use leave_out::{leave_out, LeftOut, NewTestRow};
pub use likelihood::RunLikelihood;

/// Draws of each run's calibration the layer proposes from.
const RUN_DRAWS: usize = 4000;

/// How a coordinate of the layer maps to SI units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scale {
    /// ln v of a positive value.
    Log,
    /// atanh v of a correlation.
    Atanh,
    /// v itself (a force, a stiffness; and the law's parameters'
    /// coordinates, which [`BetweenRuns::theta`] maps).
    Linear,
}

impl Scale {
    fn of(transform: Transform) -> Scale {
        match transform {
            Transform::Log => Scale::Log,
            Transform::Atanh => Scale::Atanh,
        }
    }

    pub fn to_si(self, z: f64) -> f64 {
        match self {
            Scale::Log => z.exp(),
            Scale::Atanh => z.tanh(),
            Scale::Linear => z,
        }
    }

    pub fn to_coordinate(self, v: f64) -> f64 {
        match self {
            Scale::Log => v.ln(),
            Scale::Atanh => v.atanh(),
            Scale::Linear => v,
        }
    }
}

/// One coordinate of the layer.
#[derive(Clone, Debug, PartialEq)]
pub struct Coordinate {
    /// The calibration's name of a law's coordinate (`ln G`, `ln (R0 + D1)`,
    /// `ln c0`, …), a term's (`gas_spring_n_per_m`, `force_offset_n`) or a noise
    /// parameter's (`sigma`, …).
    pub name: String,
    pub scale: Scale,
    /// The scale A_k of the half-t prior of its between-test sd.
    pub spread_prior: f64,
}

/// Where each group of coordinates sits in a point of the layer.
#[derive(Clone, Debug, PartialEq)]
pub struct Places {
    /// The law's coordinates come first.
    pub spring: Option<usize>,
    pub offset: Option<usize>,
    /// The noise model's parameters, in its order.
    pub noise: std::ops::Range<usize>,
}

/// A run calibrated alone, as the layer takes it: its id and current, its
/// calibration, and its record as the noise model sees it (for the prior
/// of its noise).
#[derive(Clone, Copy)]
pub struct LayerRun<'a> {
    pub id: &'a str,
    pub current_a: f64,
    pub cal: &'a Calibration,
    pub data: &'a RunData,
}

/// The between-run layer fitted to runs of one damper.
#[derive(Clone, Debug)]
pub struct BetweenRuns {
    pub coordinates: Vec<Coordinate>,
    pub places: Places,
    /// The damper law the runs were calibrated with, and how the layer's
    /// first coordinates (one per parameter of the law) give θ.
    pub law: LawKind,
    pub layout: Layout,
    /// The currents, in the order of each draw's centres and new tests:
    /// first the calibrated ones (increasing), then those predicted.
    pub currents: Vec<f64>,
    /// How many of `currents` runs were calibrated at.
    pub calibrated: usize,
    /// The runs it was fitted to.
    pub runs: Vec<String>,
    /// The calibrations' priors of θ, whose support a new test keeps to.
    pub priors: Vec<Prior>,
    /// The centres' curve in the current (runs at two currents or more),
    /// and the coordinates' prior scales it was fitted with.
    pub curve: Option<CurrentCurve>,
    pub scales: Vec<f64>,
    pub draws: Vec<LayerDraw>,
    /// Convergence of the Gibbs chains: the largest R̂ and the smallest
    /// bulk or tail ESS over every centre and between-test sd.
    pub max_rhat: f64,
    pub min_ess: f64,
}

/// Whether Gibbs chains with largest R̂ `max_rhat` and smallest ESS
/// `min_ess` converged: every R̂ below 1.01 and every ESS 400 or more, the
/// target the layer's blocks run to (NaN: not).
pub fn settled(max_rhat: f64, min_ess: f64) -> bool {
    max_rhat < 1.01 && min_ess >= 400.0
}

impl BetweenRuns {
    /// The layer fitted to `runs`, each calibrated alone with the same
    /// settings, on random streams of `seed`, predicting also the currents
    /// `at` (where no run was calibrated; their centres follow the curve in
    /// the current, which needs runs at two currents or more). At least one
    /// current must have two runs or more (else nothing says how tests
    /// differ).
    pub fn fit(
        runs: &[LayerRun],
        at: &[f64],
        settings: GibbsSettings,
        seed: u64,
    ) -> Result<BetweenRuns> {
        let Some(first) = runs.first() else {
            return Err(Error::Usage("the between-run layer needs runs calibrated alone".into()));
        };
        if first.cal.settings.parameter_model().is_current_law() {
            return Err(Error::Usage(
                "the between-run layer takes runs calibrated alone with one parameter set each"
                    .into(),
            ));
        }
        let mut currents: Vec<f64> = Vec::new();
        for r in runs {
            if !currents.iter().any(|c| same_current(*c, r.current_a)) {
                currents.push(r.current_a);
            }
        }
        currents.sort_by(f64::total_cmp);
        let group: Vec<usize> = runs
            .iter()
            .map(|r| currents.iter().position(|c| same_current(*c, r.current_a)).expect("listed"))
            .collect();
        if !can_fit(&runs.iter().map(|r| r.current_a).collect::<Vec<_>>()) {
            return Err(Error::Usage(
                "the between-run layer needs two runs or more at one current at least".into(),
            ));
        }
        let mut predicted: Vec<f64> = Vec::new();
        for &c in at {
            if !(c >= 0.0 && c.is_finite()) {
                return Err(Error::Usage(format!(
                    "the between-run layer predicts at currents of 0 A or more, not {c}"
                )));
            }
            if !currents.iter().chain(&predicted).any(|k| same_current(*k, c)) {
                predicted.push(c);
            }
        }
        predicted.sort_by(f64::total_cmp);
        let curve = match currents.len() {
            1 if !predicted.is_empty() => {
                return Err(Error::Usage(format!("the between-run layer predicts a current it has no runs at ({predicted:?} A) only from runs at two currents or more")));
            }
            1 => None,
            _ => Some(CurrentCurve {
                x: currents.iter().map(|c| current_coordinate(*c)).collect(),
                predict: predicted.iter().map(|c| current_coordinate(*c)).collect(),
            }),
        };
        let datas: Vec<&RunData> = runs.iter().map(|r| r.data).collect();
        let layout = theta_layout(first.cal, &datas);
        let (coordinates, places) = coordinates_of(first.cal, &layout);
        let noise = first.cal.settings.noise_model();
        let law = first.cal.settings.parameter_model().law();
        let priors = first.cal.settings.priors();
        let mut all = Vec::with_capacity(runs.len());
        for run in runs {
            if coordinates_of(run.cal, &layout) != (coordinates.clone(), places.clone())
                || run.cal.settings.sampler.coordinates != first.cal.settings.sampler.coordinates
                || run.cal.settings.priors() != priors
                || run.cal.settings.parameter_model().law() != law
            {
                return Err(Error::Usage(format!("{} was calibrated alone with another law, other priors, model terms, coordinates or noise model than the others", run.id)));
            }
            let likelihood =
                run_likelihood(run, &layout, &places, &coordinates, noise.as_ref(), &priors)
                    .ok_or_else(|| {
                        Error::Compute(format!(
                    "{}: too few draws of its calibration alone inside its prior to describe it",
                    run.id
                ))
                    })?;
            all.push(likelihood);
        }
        let scales: Vec<f64> = coordinates.iter().map(|c| c.spread_prior).collect();
        let mut chains: Vec<(Chain, rand_chacha::ChaCha8Rng, Vec<LayerDraw>)> = (0..CHAINS)
            .map(|c| {
                let chain = Chain::new(&all, &group, &scales, PRIOR_DF, curve.as_ref())
                    .expect("checked above");
                (chain, crate::rng::stream(seed, &[0xB7, runs.len() as u64, c as u64]), Vec::new())
            })
            .collect();
        // blocks of iterations until every R̂ < 1.01 and every ESS ≥ 400,
        // at most MAX_BLOCKS of them
        let (mut max_rhat, mut min_ess) = (f64::NAN, f64::NAN);
        for block in 0..MAX_BLOCKS {
            chains.par_iter_mut().for_each(|(chain, rng, kept)| {
                if block == 0 {
                    for _ in 0..settings.burn_in {
                        chain.step(rng);
                    }
                }
                for _ in 0..settings.iterations {
                    chain.step(rng);
                    kept.push(chain.draw(rng));
                }
            });
            let kept: Vec<Vec<LayerDraw>> = chains.iter().map(|c| c.2.clone()).collect();
            (max_rhat, min_ess) = convergence(&kept, currents.len());
            if settled(max_rhat, min_ess) {
                break;
            }
        }
        let chains: Vec<Vec<LayerDraw>> = chains.into_iter().map(|c| c.2).collect();
        let draws: Vec<LayerDraw> = chains.into_iter().flatten().collect();
        let calibrated = currents.len();
        currents.extend(predicted);
        Ok(BetweenRuns {
            coordinates,
            places,
            law,
            layout,
            currents,
            calibrated,
            runs: runs.iter().map(|r| r.id.to_string()).collect(),
            priors,
            curve,
            scales,
            draws,
            max_rhat,
            min_ess,
        })
    }

    /// The position of current `current_a` among the layer's currents.
    pub fn group(&self, current_a: f64) -> Option<usize> {
        self.currents.iter().position(|c| same_current(*c, current_a))
    }

    /// The number of the law's parameters.
    pub fn parameters(&self) -> usize {
        self.priors.len()
    }

    /// The names of the law's parameters, in θ's order.
    pub fn names(&self) -> Vec<&'static str> {
        self.law.law().names()
    }

    /// θ (SI; the law's parameters first, the rest zero) at the layer's
    /// point `z`; `None` outside the coordinates' range (for the B-P law's
    /// hardening coordinates, no positive R1).
    pub fn theta(&self, z: &[f64]) -> Option<LawValues> {
        let n = self.parameters();
        let log = self.layout.log_theta(&z[..n]);
        let mut theta = [0.0; MAX_LAW_PARAMETERS];
        for k in 0..n {
            theta[k] = log[k].exp();
        }
        theta[..n].iter().all(|v| v.is_finite() && *v > 0.0).then_some(theta)
    }

    /// Whether θ lies in the support of the calibrations' prior (the
    /// physical range, or tighter bounds the settings gave).
    pub fn in_support(&self, theta: &LawValues) -> bool {
        self.priors.iter().zip(theta).all(|(p, v)| p.log_density(v.ln()) > f64::NEG_INFINITY)
    }

    /// Law parameter `k` of a new test at current `group` over every kept
    /// draw (SI), sorted; draws without a θ in the prior's support left
    /// out (a new test is a physical damper).
    pub fn new_test_sorted(&self, group: usize, k: usize) -> Vec<f64> {
        let mut v: Vec<f64> = self
            .draws
            .iter()
            .filter_map(|d| self.theta(&d.new_tests[group]))
            .filter(|t| self.in_support(t))
            .map(|t| t[k])
            .collect();
        v.sort_by(f64::total_cmp);
        v
    }

    /// Law parameter `k` of the centre of current `group` (the typical
    /// test there) at every kept draw (SI), in the draws' order (paired
    /// across currents); NaN where the centre has no θ.
    pub fn centre(&self, group: usize, k: usize) -> Vec<f64> {
        self.draws.iter().map(|d| self.theta(&d.means[group]).map_or(f64::NAN, |t| t[k])).collect()
    }

    /// The between-test sd of ln θ_k at current `group`: the median of
    /// |ln θ_k(z_new) − ln θ_k(μ)| over the kept draws, divided by 0.6745
    /// (the median of |N(0, 1)|). Where θ_k's coordinate is ln θ_k it
    /// estimates √Σ_kk; for R0, R1 and D1, walked in combinations, it is
    /// the spread of each that the combinations' spreads imply.
    pub fn spread_of(&self, group: usize, k: usize) -> f64 {
        let mut d: Vec<f64> = self
            .draws
            .iter()
            .filter_map(|d| {
                Some(
                    (self.theta(&d.new_tests[group])?[k].ln()
                        - self.theta(&d.means[group])?[k].ln())
                    .abs(),
                )
            })
            .collect();
        d.sort_by(f64::total_cmp);
        quantile_sorted(&d, 0.5) / 0.674_489_750_196_081_7
    }

    /// The typical test (the centre) and a new test of each law parameter
    /// against the coil current, from `count` of the draws spread evenly:
    /// at the calibrated currents and on the comparison's grid from 0 A to
    /// 1.2× the highest ([`crate::compare::current_grid`]), the centre off
    /// the curve between and beyond the calibrated ones (its marginal at
    /// each current). `None` without a curve (runs at one current).
    pub fn against_current(&self, count: usize, seed: u64) -> Option<Vec<TypicalRow>> {
        let curve = self.curve.as_ref()?;
        let calibrated = &self.currents[..self.calibrated];
        let (lo, hi) = (calibrated[0], calibrated[self.calibrated - 1]);
        let grid = crate::compare::current_grid(calibrated);
        let d = self.coordinates.len();
        let picks = evenly_spaced(self.draws.len(), count);
        // each picked draw's calibrated centres, as the curve reads them
        let means: Vec<Vec<nalgebra::DVector<f64>>> = picks
            .iter()
            .map(|&pick| {
                self.draws[pick].means[..self.calibrated]
                    .iter()
                    .map(|m| nalgebra::DVector::from_column_slice(m))
                    .collect()
            })
            .collect();
        let mut rows = Vec::new();
        for (g, &current_a) in grid.iter().enumerate() {
            let at = calibrated.iter().position(|c| same_current(*c, current_a));
            let kind = match at {
                Some(_) => CurrentKind::Calibrated,
                None if current_a > lo && current_a < hi => CurrentKind::Between,
                None => CurrentKind::Outside,
            };
            let here =
                CurrentCurve { x: curve.x.clone(), predict: vec![current_coordinate(current_a)] };
            let mut centres: Vec<LawValues> = Vec::new();
            let mut tests: Vec<LawValues> = Vec::new();
            for (i, &pick) in picks.iter().enumerate() {
                let draw = &self.draws[pick];
                let mut rng = crate::rng::stream(seed, &[0xB9, g as u64, i as u64]);
                let centre: Vec<f64> = match at {
                    Some(c) => draw.means[c].clone(),
                    None => {
                        curve::predict_centres(&here, &means[i], &draw.eta, &self.scales, &mut rng)
                            .remove(0)
                            .as_slice()
                            .to_vec()
                    }
                };
                let e: Vec<f64> = (0..d).map(|_| rng.sample::<f64, _>(StandardNormal)).collect();
                let test = draw.new_test_about(&centre, &e);
                centres.extend(self.theta(&centre).filter(|t| self.in_support(t)));
                tests.extend(self.theta(&test).filter(|t| self.in_support(t)));
            }
            for (k, parameter) in self.names().iter().enumerate() {
                let q = |v: &[LawValues]| {
                    let mut x: Vec<f64> = v.iter().map(|t| t[k]).collect();
                    x.sort_by(f64::total_cmp);
                    [0.05, 0.5, 0.95].map(|p| quantile_sorted(&x, p))
                };
                rows.push(TypicalRow {
                    parameter: parameter.to_string(),
                    current_a,
                    kind,
                    centre: q(&centres),
                    new_test: q(&tests),
                });
            }
        }
        Some(rows)
    }

    /// `count` draws of a new test at current `group` for the run `data`
    /// (whose noise prior its noise must satisfy), spread evenly over the
    /// kept iterations: each new test inside the support of the
    /// calibrations' prior and of the run's noise prior, drawn again (from
    /// the same iteration's centre and covariance) up to a few times where
    /// it falls outside. Iterations whose every try falls outside are left
    /// out: their count is the second value.
    pub fn new_tests(
        &self,
        group: usize,
        cal: &Calibration,
        data: &RunData,
        count: usize,
        seed: u64,
    ) -> (Vec<Draw>, usize) {
        let noise = cal.settings.noise_model();
        let d = self.coordinates.len();
        let mut out = Vec::with_capacity(count);
        let mut outside = 0;
        for (i, pick) in evenly_spaced(self.draws.len(), count).into_iter().enumerate() {
            let draw = &self.draws[pick];
            let mut rng = crate::rng::stream(seed, &[0xB8, i as u64]);
            let found = (0..TRIES).find_map(|t| {
                let z = match t {
                    0 => draw.new_tests[group].clone(),
                    _ => draw.new_test(
                        group,
                        &(0..d).map(|_| rng.sample::<f64, _>(StandardNormal)).collect::<Vec<f64>>(),
                    ),
                };
                let theta = self.theta(&z)?;
                let coords = self.noise_coordinates(&z);
                (self.in_support(&theta) && noise.log_prior(data, &coords) > f64::NEG_INFINITY)
                    .then(|| self.draw_at(theta, &z))
            });
            match found {
                Some(draw) => out.push(draw),
                None => outside += 1,
            }
        }
        (out, outside)
    }

    /// The noise model's coordinates at layer point `z`.
    fn noise_coordinates(&self, z: &[f64]) -> NoiseValues {
        let mut c = [0.0; MAX_PARAMETERS];
        for (p, k) in self.places.noise.clone().enumerate() {
            c[p] = z[k];
        }
        c
    }

    /// The draw of a run with layer point `z`, whose θ is `theta`.
    fn draw_at(&self, theta: LawValues, z: &[f64]) -> Draw {
        let mut noise = [0.0; MAX_PARAMETERS];
        for (p, k) in self.places.noise.clone().enumerate() {
            noise[p] = self.coordinates[k].scale.to_si(z[k]);
        }
        Draw {
            law: self.law,
            values: theta,
            field: None,
            spring_n_per_m: self.places.spring.map_or(0.0, |k| z[k]),
            offset_n: self.places.offset.map_or(0.0, |k| z[k]),
            noise,
        }
    }
}

/// The largest R̂ and smallest ESS of the Gibbs `chains` over every
/// centre of the `calibrated` currents and every between-test sd (the
/// rank-normalised split R̂ and bulk and tail ESS of the calibrations).
fn convergence(chains: &[Vec<LayerDraw>], calibrated: usize) -> (f64, f64) {
    let steps = chains.iter().map(Vec::len).min().unwrap_or(0);
    let Some(d) = chains.first().and_then(|c| c.first()).map(|d| d.means[0].len()) else {
        return (f64::NAN, f64::NAN);
    };
    let dim = calibrated * d + d;
    let mut positions = Vec::with_capacity(steps * chains.len() * dim);
    for step in 0..steps {
        for draws in chains {
            let draw = &draws[step];
            positions.extend(draw.means[..calibrated].iter().flatten().copied());
            positions.extend((0..d).map(|k| draw.sd(k)));
        }
    }
    let n = steps * chains.len();
    let trace = Chains {
        dim,
        ensembles: chains.len(),
        walkers: 1,
        positions,
        log_prob: vec![0.0; n],
        accepted: vec![true; n],
    };
    let diagnostics = Diagnostics::compute(&trace, 0);
    (diagnostics.max_rhat(), diagnostics.min_ess())
}

/// One row of `typical_test.parquet`: a law's parameter at one coil current,
/// the 5, 50 and 95 % quantiles of the typical test there (the layer's
/// centre) and of a new test (SI).
#[derive(Clone, Debug, PartialEq)]
pub struct TypicalRow {
    pub parameter: String,
    pub current_a: f64,
    pub kind: CurrentKind,
    pub centre: [f64; 3],
    pub new_test: [f64; 3],
}

/// Tries at a new test inside the priors' support per kept iteration.
const TRIES: usize = 20;

/// The layer's coordinates for calibrations made with `cal`'s settings,
/// the law's parameters walked as `layout` walks them.
fn coordinates_of(cal: &Calibration, layout: &Layout) -> (Vec<Coordinate>, Places) {
    let names = layout.coordinate_names();
    let mut coordinates: Vec<Coordinate> = names[layout.theta.clone()]
        .iter()
        .map(|n| Coordinate { name: n.clone(), scale: Scale::Linear, spread_prior: 1.0 })
        .collect();
    let terms = &cal.settings.terms;
    let place = |c: &mut Vec<Coordinate>, on: bool, name: &str, sd: f64| {
        on.then(|| {
            c.push(Coordinate { name: name.to_string(), scale: Scale::Linear, spread_prior: sd });
            c.len() - 1
        })
    };
    let spring = place(
        &mut coordinates, terms.gas_spring, "gas_spring_n_per_m", terms.gas_spring_sd_n_per_m,
    );
    let offset =
        place(&mut coordinates, terms.force_offset, "force_offset_n", terms.force_offset_sd_n);
    let start = coordinates.len();
    for p in cal.sample.layout.noise_parameters {
        coordinates.push(Coordinate {
            name: p.name.to_string(),
            scale: Scale::of(p.transform),
            spread_prior: 1.0,
        });
    }
    let noise = start..coordinates.len();
    (coordinates, Places { spring, offset, noise })
}

/// The layout whose coordinates of θ the layer takes: the calibrations'
/// own, hardened at the median work of `runs`.
fn theta_layout(cal: &Calibration, runs: &[&RunData]) -> Layout {
    let ids: Vec<String> = runs.iter().map(|r| r.id.clone()).collect();
    let settings = &cal.settings;
    let model = settings.parameter_model();
    let mut layout = Layout::new(
        &model,
        &ids,
        settings.noise_model().as_ref(),
        settings.sampler.coordinates,
        &ModelTerms::default(),
    );
    if settings.sampler.coordinates == Coordinates::Hardening {
        let owned: Vec<RunData> = runs.iter().map(|r| (*r).clone()).collect();
        layout.harden(&model, Hardening::reference_work(&owned));
    }
    layout
}

/// The likelihood of `run`'s record in the layer's coordinates, from the
/// draws of its calibration alone and its prior p₀ there (the priors of
/// ln θ with the Jacobian of θ's coordinates in `layout`, the terms' and
/// the noise's).
fn run_likelihood(
    run: &LayerRun,
    layout: &Layout,
    places: &Places,
    coordinates: &[Coordinate],
    noise: &dyn NoiseModel,
    priors: &[Prior],
) -> Option<RunLikelihood> {
    let cal = run.cal;
    let sample = &cal.sample;
    let terms = &cal.settings.terms;
    let normal = |v: f64, sd: f64| -0.5 * (v / sd) * (v / sd);
    let log_prior = |z: &[f64]| -> f64 {
        let log_theta = layout.log_theta(&z[..priors.len()]);
        let mut lp: f64 = priors.iter().zip(&log_theta).map(|(p, v)| p.log_density(*v)).sum();
        if !lp.is_finite() {
            return f64::NEG_INFINITY;
        }
        lp += layout.log_jacobian(z, &log_theta);
        if let Some(k) = places.spring {
            lp += normal(z[k], terms.gas_spring_sd_n_per_m);
        }
        if let Some(k) = places.offset {
            lp += normal(z[k], terms.force_offset_sd_n);
        }
        let mut coords = [0.0; MAX_PARAMETERS];
        for (p, k) in places.noise.clone().enumerate() {
            coords[p] = z[k];
        }
        lp + noise.log_prior(run.data, &coords)
    };
    let mut points = Vec::new();
    for (s, c) in cal.draw_positions(RUN_DRAWS) {
        let point = sample.chains.point(s, c);
        let values = sample.values_at(s, c, cal.record.current_a);
        let log_theta: Vec<f64> = values[..priors.len()].iter().map(|v| v.ln()).collect();
        let mut z = layout.theta_coordinates(&log_theta);
        let (spring, offset) = sample.layout.terms(point, 0);
        if places.spring.is_some() {
            z.push(spring);
        }
        if places.offset.is_some() {
            z.push(offset);
        }
        let values = sample.layout.noise_values(point, 0);
        for (p, k) in places.noise.clone().enumerate() {
            z.push(coordinates[k].scale.to_coordinate(values[p]));
        }
        if z.iter().all(|v| v.is_finite()) && log_prior(&z).is_finite() {
            points.push(z);
        }
    }
    let steps: Vec<f64> = coordinates.iter().map(|c| 1e-3 * c.spread_prior).collect();
    RunLikelihood::from_draws(&points, &log_prior, &steps)
}

/// Whether the layer can be fitted to runs at `currents` (one entry a
/// run): two runs or more at one current at least, where the spread
/// between tests is measured.
pub(super) fn can_fit(currents: &[f64]) -> bool {
    currents.iter().any(|c| currents.iter().filter(|k| same_current(**k, *c)).count() >= 2)
}
