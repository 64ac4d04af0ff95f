//! The between-run layer: the runs of one damper as draws from a population
//! of tests, so that a calibration can say what **a new test** of the
//! damper would give, not only what these records give.
//!
//! Each run i, at coil current c(i), has its own parameters z_i: the B-P
//! parameters in the calibration's own coordinates (by default the
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
//! It is fitted exactly in two stages (Lunn, Barrett, Sweeting &
//! Richardson 2013): each run calibrated alone under its prior p₀ gives
//! draws of p(z_i | y_i) ∝ L_i(z_i) p₀(z_i); a Gibbs sampler then updates
//! each z_i by an independence Metropolis-Hastings step that proposes one
//! of those draws, accepted with the ratio of N(z | μ, Σ)/p₀(z) at the
//! proposal and at the current value, and draws the centres, Σ and a from
//! their conditionals (normal, inverse Wishart by Bartlett's
//! decomposition, inverse gamma). No log-density of the B-P law is
//! computed: the runs' own chains carry their likelihoods.

use nalgebra::{Cholesky, DMatrix, DVector};
use rand::{Rng, RngExt};
use rand_distr::{ChiSquared, Gamma, StandardNormal};
use rayon::prelude::*;

use crate::calibrate::Calibration;
use crate::data::{same_current, Campaign, RecordPart, RunData};
use crate::error::{Error, Result};
use crate::model::{Params, PARAM_NAMES};
use crate::noise::{NoiseModel, NoiseValues, Transform, MAX_PARAMETERS};
use crate::posterior::layout::Hardening;
use crate::posterior::{evenly_spaced, Coordinates, Draw, Layout, ModelTerms, ParameterModel, Prior};
use crate::predict::{predict_run, RunPrediction};
use crate::sampler::quantile_sorted;

/// Draws of each run's calibration the layer proposes from.
const RUN_DRAWS: usize = 4000;

/// Degrees of freedom ν of the Huang-Wand prior: half-t(2) sds, uniform
/// correlations.
pub const PRIOR_DF: f64 = 2.0;

/// How the Gibbs sampler runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GibbsSettings {
    /// Iterations kept (after the burn-in).
    pub iterations: usize,
    pub burn_in: usize,
    /// Independence proposals per run and iteration.
    pub proposals: usize,
}

impl Default for GibbsSettings {
    fn default() -> Self {
        GibbsSettings { iterations: 20_000, burn_in: 1000, proposals: 8 }
    }
}

/// How a coordinate of the layer maps to SI units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scale {
    /// ln v of a positive value.
    Log,
    /// atanh v of a correlation.
    Atanh,
    /// v itself (a force, a stiffness; and the B-P parameters' coordinates,
    /// which [`BetweenRuns::theta`] maps).
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
    /// The calibration's name of a B-P coordinate (`ln G`, `ln (R0 + D1)`,
    /// …), a term's (`gas_spring_n_per_m`, `force_offset_n`) or a noise
    /// parameter's (`sigma`, …).
    pub name: String,
    pub scale: Scale,
    /// The scale A_k of the half-t prior of its between-test sd.
    pub spread_prior: f64,
}

/// Where each group of coordinates sits in a point of the layer.
#[derive(Clone, Debug, PartialEq)]
pub struct Places {
    /// The seven B-P coordinates come first.
    pub spring: Option<usize>,
    pub offset: Option<usize>,
    /// The noise model's parameters, in its order.
    pub noise: std::ops::Range<usize>,
}

/// Draws of one run's calibration in the layer's coordinates, with the
/// log-density of its prior p₀ at each.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunDraws {
    pub points: Vec<Vec<f64>>,
    pub log_prior: Vec<f64>,
}

/// One kept iteration of the Gibbs sampler, in the layer's coordinates:
/// each current's centre μ_c, the Cholesky factor of Σ (lower, column
/// major), and a new test at each current, z_new ~ N(μ_c, Σ).
#[derive(Clone, Debug, PartialEq)]
pub struct LayerDraw {
    pub means: Vec<Vec<f64>>,
    pub factor: Vec<f64>,
    pub new_tests: Vec<Vec<f64>>,
}

impl LayerDraw {
    /// The between-test sd of coordinate `k`: √Σ_kk.
    pub fn sd(&self, k: usize) -> f64 {
        let d = self.means.first().map_or(0, Vec::len);
        (0..=k).map(|j| self.factor[j * d + k].powi(2)).sum::<f64>().sqrt()
    }

    /// A new test at current `group` from standard normals `e`: μ + L e.
    fn new_test(&self, group: usize, e: &[f64]) -> Vec<f64> {
        let d = e.len();
        (0..d).map(|k| self.means[group][k] + (0..=k).map(|j| self.factor[j * d + k] * e[j]).sum::<f64>()).collect()
    }
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
    /// How the first seven coordinates give θ.
    pub layout: Layout,
    /// The currents, in the order of each draw's centres and new tests.
    pub currents: Vec<f64>,
    /// The runs it was fitted to.
    pub runs: Vec<String>,
    /// The calibrations' priors of θ, whose support a new test keeps to.
    pub priors: [Prior; 7],
    pub draws: Vec<LayerDraw>,
    /// Acceptance of the runs' independence proposals.
    pub acceptance: f64,
}

impl BetweenRuns {
    /// The layer fitted to `runs`, each calibrated alone with the same
    /// settings, on random streams of `seed`. At least one current must have
    /// two runs or more (else nothing says how tests differ).
    pub fn fit(runs: &[LayerRun], settings: GibbsSettings, seed: u64) -> Result<BetweenRuns> {
        let Some(first) = runs.first() else {
            return Err(Error::Usage("the between-run layer needs runs calibrated alone".into()));
        };
        if first.cal.settings.parameter_model() != ParameterModel::PerCurrent {
            return Err(Error::Usage("the between-run layer takes runs calibrated alone with one parameter set each".into()));
        }
        let mut currents: Vec<f64> = Vec::new();
        for r in runs {
            if !currents.iter().any(|c| same_current(*c, r.current_a)) {
                currents.push(r.current_a);
            }
        }
        currents.sort_by(f64::total_cmp);
        let group: Vec<usize> = runs.iter().map(|r| currents.iter().position(|c| same_current(*c, r.current_a)).expect("listed")).collect();
        if !(0..currents.len()).any(|g| group.iter().filter(|&&h| h == g).count() >= 2) {
            return Err(Error::Usage("the between-run layer needs two runs or more at one current at least".into()));
        }
        let datas: Vec<&RunData> = runs.iter().map(|r| r.data).collect();
        let layout = theta_layout(first.cal, &datas);
        let (coordinates, places) = coordinates_of(first.cal, &layout);
        let noise = first.cal.settings.noise_model();
        let priors = first.cal.settings.priors();
        let mut all = Vec::with_capacity(runs.len());
        for run in runs {
            if coordinates_of(run.cal, &layout) != (coordinates.clone(), places.clone())
                || run.cal.settings.sampler.coordinates != first.cal.settings.sampler.coordinates
                || run.cal.settings.priors() != priors
            {
                return Err(Error::Usage(format!("{} was calibrated alone with other priors, model terms, coordinates or noise model than the others", run.id)));
            }
            let draws = run_draws(run, &layout, &places, &coordinates, noise.as_ref(), &priors);
            if draws.points.is_empty() {
                return Err(Error::Compute(format!("{}: no draw of its calibration alone lies inside its prior", run.id)));
            }
            all.push(draws);
        }
        let scales: Vec<f64> = coordinates.iter().map(|c| c.spread_prior).collect();
        let mut rng = crate::rng::stream(seed, &[0xB7, runs.len() as u64]);
        let (draws, acceptance) = gibbs(&all, &group, &scales, PRIOR_DF, settings, &mut rng);
        Ok(BetweenRuns { coordinates, places, layout, currents, runs: runs.iter().map(|r| r.id.to_string()).collect(), priors, draws, acceptance })
    }

    /// The position of current `current_a` among the layer's currents.
    pub fn group(&self, current_a: f64) -> Option<usize> {
        self.currents.iter().position(|c| same_current(*c, current_a))
    }

    /// θ (SI) at the layer's point `z`; `None` outside the coordinates'
    /// range (no positive R1).
    pub fn theta(&self, z: &[f64]) -> Option<[f64; 7]> {
        let log = self.layout.log_theta(&z[..7]);
        let theta: [f64; 7] = std::array::from_fn(|k| log[k].exp());
        theta.iter().all(|v| v.is_finite() && *v > 0.0).then_some(theta)
    }

    /// Whether θ lies in the support of the calibrations' prior (the
    /// physical range, or tighter bounds the settings gave).
    pub fn in_support(&self, theta: &[f64; 7]) -> bool {
        self.priors.iter().zip(theta).all(|(p, v)| p.log_density(v.ln()) > f64::NEG_INFINITY)
    }

    /// B-P parameter `k` of a new test at current `group` over every kept
    /// draw (SI), sorted; draws without a θ in the prior's support left
    /// out (a new test is a physical damper).
    pub fn new_test_sorted(&self, group: usize, k: usize) -> Vec<f64> {
        let mut v: Vec<f64> = self.draws.iter().filter_map(|d| self.theta(&d.new_tests[group])).filter(|t| self.in_support(t)).map(|t| t[k]).collect();
        v.sort_by(f64::total_cmp);
        v
    }

    /// B-P parameter `k` of the centre of current `group` (the typical
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
            .filter_map(|d| Some((self.theta(&d.new_tests[group])?[k].ln() - self.theta(&d.means[group])?[k].ln()).abs()))
            .collect();
        d.sort_by(f64::total_cmp);
        quantile_sorted(&d, 0.5) / 0.674_489_750_196_081_7
    }

    /// `count` draws of a new test at current `group` for the run `data`
    /// (whose noise prior its noise must satisfy), spread evenly over the
    /// kept iterations: each new test inside the support of the
    /// calibrations' prior and of the run's noise prior, drawn again (from
    /// the same iteration's centre and covariance) up to a few times where
    /// it falls outside. Iterations whose every try falls outside are left
    /// out: their count is the second value.
    pub fn new_tests(&self, group: usize, cal: &Calibration, data: &RunData, count: usize, seed: u64) -> (Vec<Draw>, usize) {
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
                    _ => draw.new_test(group, &(0..d).map(|_| rng.sample::<f64, _>(StandardNormal)).collect::<Vec<f64>>()),
                };
                let theta = self.theta(&z)?;
                let coords = self.noise_coordinates(&z);
                (self.in_support(&theta) && noise.log_prior(data, &coords) > f64::NEG_INFINITY).then(|| self.draw_at(theta, &z))
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
    fn draw_at(&self, theta: [f64; 7], z: &[f64]) -> Draw {
        let mut noise = [0.0; MAX_PARAMETERS];
        for (p, k) in self.places.noise.clone().enumerate() {
            noise[p] = self.coordinates[k].scale.to_si(z[k]);
        }
        Draw {
            params: Params::from_array(theta),
            field: None,
            spring_n_per_m: self.places.spring.map_or(0.0, |k| z[k]),
            offset_n: self.places.offset.map_or(0.0, |k| z[k]),
            noise,
        }
    }
}

/// Tries at a new test inside the priors' support per kept iteration.
const TRIES: usize = 20;

/// The layer's coordinates for calibrations made with `cal`'s settings,
/// the B-P parameters walked as `layout` walks them.
fn coordinates_of(cal: &Calibration, layout: &Layout) -> (Vec<Coordinate>, Places) {
    let names = layout.coordinate_names();
    let mut coordinates: Vec<Coordinate> = names[..PARAM_NAMES.len()].iter().map(|n| Coordinate { name: n.clone(), scale: Scale::Linear, spread_prior: 1.0 }).collect();
    let terms = &cal.settings.terms;
    let place = |c: &mut Vec<Coordinate>, on: bool, name: &str, sd: f64| {
        on.then(|| {
            c.push(Coordinate { name: name.to_string(), scale: Scale::Linear, spread_prior: sd });
            c.len() - 1
        })
    };
    let spring = place(&mut coordinates, terms.gas_spring, "gas_spring_n_per_m", terms.gas_spring_sd_n_per_m);
    let offset = place(&mut coordinates, terms.force_offset, "force_offset_n", terms.force_offset_sd_n);
    let start = coordinates.len();
    for p in cal.sample.layout.noise_parameters {
        coordinates.push(Coordinate { name: p.name.to_string(), scale: Scale::of(p.transform), spread_prior: 1.0 });
    }
    let noise = start..coordinates.len();
    (coordinates, Places { spring, offset, noise })
}

/// The layout whose coordinates of θ the layer takes: the calibrations'
/// own, hardened at the median work of `runs`.
fn theta_layout(cal: &Calibration, runs: &[&RunData]) -> Layout {
    let ids: Vec<String> = runs.iter().map(|r| r.id.clone()).collect();
    let settings = &cal.settings;
    let model = ParameterModel::PerCurrent;
    let mut layout = Layout::new(&model, &ids, settings.noise_model().as_ref(), settings.sampler.coordinates, &ModelTerms::default());
    if settings.sampler.coordinates == Coordinates::Hardening {
        let owned: Vec<RunData> = runs.iter().map(|r| (*r).clone()).collect();
        layout.harden(&model, Hardening::reference_work(&owned));
    }
    layout
}

/// The draws of `run`'s calibration alone in the layer's coordinates, with
/// ln p₀ at each (the priors of ln θ with the Jacobian of θ's coordinates
/// in `layout`, the terms' and the noise's).
fn run_draws(run: &LayerRun, layout: &Layout, places: &Places, coordinates: &[Coordinate], noise: &dyn NoiseModel, priors: &[Prior; 7]) -> RunDraws {
    let cal = run.cal;
    let sample = &cal.sample;
    let terms = &cal.settings.terms;
    let normal = |v: f64, sd: f64| -0.5 * (v / sd) * (v / sd);
    let mut out = RunDraws::default();
    for (s, c) in cal.draw_positions(RUN_DRAWS) {
        let point = sample.chains.point(s, c);
        let log_theta: Vec<f64> = sample.params_at(s, c, cal.record.current_a).to_array().iter().map(|v| v.ln()).collect();
        let mut z = layout.theta_coordinates(&log_theta);
        let mut log_prior: f64 = priors.iter().zip(&log_theta).map(|(p, v)| p.log_density(*v)).sum::<f64>() + layout.log_jacobian(&z, &log_theta);
        let (spring, offset) = sample.layout.terms(point, 0);
        if places.spring.is_some() {
            z.push(spring);
            log_prior += normal(spring, terms.gas_spring_sd_n_per_m);
        }
        if places.offset.is_some() {
            z.push(offset);
            log_prior += normal(offset, terms.force_offset_sd_n);
        }
        let values = sample.layout.noise_values(point, 0);
        let mut coords = [0.0; MAX_PARAMETERS];
        for (p, k) in places.noise.clone().enumerate() {
            coords[p] = coordinates[k].scale.to_coordinate(values[p]);
            z.push(coords[p]);
        }
        log_prior += noise.log_prior(run.data, &coords);
        if z.iter().all(|v| v.is_finite()) && log_prior.is_finite() {
            out.points.push(z);
            out.log_prior.push(log_prior);
        }
    }
    out
}

/// The two-stage Gibbs sampler of the layer: `runs` each a set of draws of
/// p(z_i | y_i) under the prior p₀ (with ln p₀ at each), run i at current
/// `group[i]` (0, 1, …), the half-t scales of the between-test sds
/// `scales`, ν = `nu`. The kept iterations and the acceptance of the runs'
/// independence proposals.
pub fn gibbs(runs: &[RunDraws], group: &[usize], scales: &[f64], nu: f64, settings: GibbsSettings, rng: &mut impl Rng) -> (Vec<LayerDraw>, f64) {
    let m = runs.len();
    let d = scales.len();
    let groups = group.iter().max().map_or(0, |g| g + 1);
    if m < 2 || runs.iter().any(|r| r.points.is_empty()) {
        return (Vec::new(), f64::NAN);
    }
    let members: Vec<Vec<usize>> = (0..groups).map(|g| (0..m).filter(|&i| group[i] == g).collect()).collect();
    let normals = |rng: &mut dyn rand::Rng| DVector::from_iterator(d, (0..d).map(|_| RngExt::sample::<f64, _>(rng, StandardNormal)));
    let mut at: Vec<usize> = runs.iter().map(|r| rng.random_range(0..r.points.len())).collect();
    let z_of = |i: usize, at: &[usize]| DVector::from_column_slice(&runs[i].points[at[i]]);
    let mut a: Vec<f64> = scales.iter().map(|s| s * s).collect();
    let mut sigma = DMatrix::from_diagonal(&DVector::from_iterator(d, a.iter().copied()));
    let mut means = vec![DVector::<f64>::zeros(d); groups];
    let (mut accepted, mut proposed) = (0usize, 0usize);
    let mut kept = Vec::with_capacity(settings.iterations);
    for iteration in 0..settings.burn_in + settings.iterations {
        // μ_c | Σ, z ~ N(z̄_c, Σ/m_c)
        let factor = cholesky(&sigma);
        for (g, mean) in means.iter_mut().enumerate() {
            let n = members[g].len() as f64;
            let zbar = members[g].iter().map(|&i| z_of(i, &at)).fold(DVector::zeros(d), |acc, z| acc + z) / n;
            *mean = zbar + &factor * normals(rng) / n.sqrt();
        }
        // Σ | μ, z, a ~ IW(ν + d − 1 + m, 2ν diag(1/a) + Σ_i (z_i − μ_c(i))(z_i − μ_c(i))ᵀ)
        let mut psi = DMatrix::from_diagonal(&DVector::from_iterator(d, a.iter().map(|a| 2.0 * nu / a)));
        for i in 0..m {
            let r = z_of(i, &at) - &means[group[i]];
            psi += &r * r.transpose();
        }
        sigma = inverse_wishart(&psi, nu + (d - 1 + m) as f64, rng);
        let precision = Cholesky::new(sigma.clone()).map_or_else(|| DMatrix::identity(d, d), |c| c.inverse());
        // a_k | Σ ~ IG((ν + d)/2, ν (Σ⁻¹)_kk + 1/A_k²)
        for k in 0..d {
            let rate = nu * precision[(k, k)] + 1.0 / (scales[k] * scales[k]);
            let g: f64 = rng.sample(Gamma::new(0.5 * (nu + d as f64), 1.0 / rate).expect("positive shape and scale"));
            a[k] = 1.0 / g;
        }
        // each z_i given (μ, Σ): independence proposals from its own draws
        for (i, run) in runs.iter().enumerate() {
            let mean = &means[group[i]];
            let log_weight = |c: usize| -> f64 {
                let r = DVector::from_column_slice(&run.points[c]) - mean;
                -0.5 * r.dot(&(&precision * &r)) - run.log_prior[c]
            };
            let mut current = log_weight(at[i]);
            for _ in 0..settings.proposals {
                let c = rng.random_range(0..run.points.len());
                let proposal = log_weight(c);
                proposed += 1;
                if rng.random::<f64>().ln() < proposal - current {
                    (at[i], current) = (c, proposal);
                    accepted += 1;
                }
            }
        }
        if iteration >= settings.burn_in {
            let factor = cholesky(&sigma);
            let new_tests = means.iter().map(|mean| (mean + &factor * normals(rng)).as_slice().to_vec()).collect();
            kept.push(LayerDraw { means: means.iter().map(|m| m.as_slice().to_vec()).collect(), factor: factor.as_slice().to_vec(), new_tests });
        }
    }
    (kept, accepted as f64 / proposed.max(1) as f64)
}

/// The lower Cholesky factor of a covariance (of its diagonal, should
/// rounding have made it indefinite).
fn cholesky(sigma: &DMatrix<f64>) -> DMatrix<f64> {
    match Cholesky::new(sigma.clone()) {
        Some(c) => c.l(),
        None => DMatrix::from_diagonal(&sigma.diagonal().map(|v| v.max(0.0).sqrt())),
    }
}

/// A draw of IW(`dof`, `psi`): W ~ Wishart(dof, Ψ⁻¹) by Bartlett's
/// decomposition, Σ = W⁻¹.
fn inverse_wishart(psi: &DMatrix<f64>, dof: f64, rng: &mut impl Rng) -> DMatrix<f64> {
    let d = psi.nrows();
    let psi_inverse = Cholesky::new(psi.clone()).map_or_else(|| DMatrix::identity(d, d), |c| c.inverse());
    let l = cholesky(&psi_inverse);
    let mut b = DMatrix::<f64>::zeros(d, d);
    for i in 0..d {
        b[(i, i)] = rng.sample::<f64, _>(ChiSquared::new(dof - i as f64).expect("positive degrees of freedom")).sqrt();
        for j in 0..i {
            b[(i, j)] = rng.sample(StandardNormal);
        }
    }
    let lb = l * b;
    let w = &lb * lb.transpose();
    Cholesky::new(w.clone()).map_or_else(|| DMatrix::from_diagonal(&w.diagonal().map(|v| 1.0 / v)), |c| c.inverse())
}

/// Each run of `campaign` predicted as a new test by the layer fitted to
/// every other run calibrated alone (`alone`: runs of this damper at any
/// current, by id, with their records as the noise model sees them):
/// leave-one-run-out with the between-run layer. `joint` is the calibration
/// of `campaign`'s current, whose integrator and noise model make the
/// bands. A run whose current keeps no other run cannot be predicted (the
/// layer knows no centre there) and is left out; so is one the layer
/// cannot be fitted without.
pub fn leave_one_out(joint: &Calibration, campaign: &Campaign, alone: &[LayerRun], draws: usize, replicates: usize, seed: u64) -> Result<Vec<RunPrediction>> {
    let settings = joint.predict_settings(replicates, seed);
    let smooth = joint.settings.likelihood.smooth_strain_ms;
    let held: Vec<(usize, &std::sync::Arc<crate::data::Run>, &LayerRun)> = campaign
        .runs
        .iter()
        .enumerate()
        .filter_map(|(j, run)| {
            let own = alone.iter().find(|r| r.id == run.id())?;
            let others = alone.iter().filter(|r| r.id != run.id() && same_current(r.current_a, run.spec.current_a)).count();
            (others >= 1).then_some((j, run, own))
        })
        .collect();
    held.par_iter()
        .map(|&(j, run, own)| {
            let others: Vec<LayerRun> = alone.iter().filter(|r| r.id != run.id()).copied().collect();
            let layer = BetweenRuns::fit(&others, GibbsSettings::default(), seed ^ (0x1_0000 + j as u64))?;
            let group = layer.group(run.spec.current_a).expect("a run at its current");
            let data = RunData::from_run(run, RecordPart::WholeRecord, smooth);
            let (new, outside) = layer.new_tests(group, own.cal, &data, draws, seed ^ (0x2_0000 + j as u64));
            let mut prediction = predict_run(run, &data, j, &new, &settings, false, &|| {})?;
            prediction.coverage.failed_draws += outside;
            Ok(prediction)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use statrs::distribution::{ContinuousCDF, Normal};

    /// ln of the half-t(ν, A) density of τ, up to a constant.
    fn half_t(tau: f64, nu: f64, scale: f64) -> f64 {
        -0.5 * (nu + 1.0) * (1.0 + (tau / scale).powi(2) / nu).ln()
    }

    /// The one-coordinate model on a grid of τ, an independent computation
    /// of a new test's distribution function at group `target`: runs in
    /// groups (`y`, `s`, `group`), each run's posterior N(y_i, s_i²) under
    /// a flat prior, z_i ~ N(μ_g, τ²), μ_g flat and integrated exactly,
    /// τ ~ half-t(ν, A).
    fn grid_cdf(y: &[f64], s: &[f64], group: &[usize], target: usize, nu: f64, scale: f64, x: f64) -> f64 {
        let spread = y.iter().cloned().fold(f64::MIN, f64::max) - y.iter().cloned().fold(f64::MAX, f64::min);
        let top = 30.0 * (spread + s.iter().cloned().fold(0.0, f64::max) + scale);
        let groups = group.iter().max().unwrap() + 1;
        let n = 30_001;
        let (mut total, mut acc) = (0.0, 0.0);
        for i in 1..n {
            let tau = top * i as f64 / (n - 1) as f64;
            let mut log_marginal = half_t(tau, nu, scale);
            let mut predictive = (0.0, 0.0);
            for g in 0..groups {
                let members: Vec<usize> = (0..y.len()).filter(|&i| group[i] == g).collect();
                let w: Vec<f64> = members.iter().map(|&i| 1.0 / (s[i] * s[i] + tau * tau)).collect();
                let sw: f64 = w.iter().sum();
                let mu = members.iter().zip(&w).map(|(&i, w)| y[i] * w).sum::<f64>() / sw;
                log_marginal += 0.5 * w.iter().map(|w| w.ln()).sum::<f64>() - 0.5 * sw.ln() - 0.5 * members.iter().zip(&w).map(|(&i, w)| (y[i] - mu).powi(2) * w).sum::<f64>();
                if g == target {
                    predictive = (mu, (1.0 / sw + tau * tau).sqrt());
                }
            }
            let weight = log_marginal.exp();
            total += weight;
            acc += weight * Normal::new(predictive.0, predictive.1).unwrap().cdf(x);
        }
        acc / total
    }

    /// The quantile `p` of [`grid_cdf`], by bisection.
    fn grid_quantile(y: &[f64], s: &[f64], group: &[usize], target: usize, nu: f64, p: f64) -> f64 {
        let (mut lo, mut hi) = (-60.0, 60.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if grid_cdf(y, s, group, target, nu, 1.0, mid) < p {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    fn quantiles(draws: &[LayerDraw], group: usize, k: usize) -> [f64; 3] {
        let mut v: Vec<f64> = draws.iter().map(|d| d.new_tests[group][k]).collect();
        v.sort_by(f64::total_cmp);
        [quantile_sorted(&v, 0.05), quantile_sorted(&v, 0.5), quantile_sorted(&v, 0.95)]
    }

    /// Draws of N(mean, sd²) in `dims` independent coordinates, `count` of
    /// them, with ln p₀ = `log_prior` of the first.
    fn normal_draws(mean: &[f64], sd: f64, count: usize, log_prior: impl Fn(f64) -> f64, rng: &mut impl Rng) -> RunDraws {
        let points: Vec<Vec<f64>> = (0..count).map(|_| mean.iter().map(|m| m + sd * rng.sample::<f64, _>(StandardNormal)).collect()).collect();
        let log_prior = points.iter().map(|p| log_prior(p[0])).collect();
        RunDraws { points, log_prior }
    }

    /// Precise runs in two groups, one coordinate: a new test's 90 %
    /// interval at each current is set by the spread about each current's
    /// own centre, learned from both. Against the grid: the 5, 50 and 95 %
    /// quantiles within 0.05 (half-widths about 1.2): over four seeds the
    /// quantiles scattered with sd at most 0.008 at 100 000 iterations, so
    /// 0.05 is six Monte Carlo se.
    #[test]
    fn precise_runs_in_two_groups_share_their_spread() {
        let y = [-0.6, -0.1, 0.2, 3.0, 3.5];
        let group = [0, 0, 0, 1, 1];
        let mut rng = crate::rng::stream(11, &[1]);
        let runs: Vec<RunDraws> = y.iter().map(|&m| normal_draws(&[m], 0.001, 2000, |_| 0.0, &mut rng)).collect();
        let settings = GibbsSettings { iterations: 100_000, burn_in: 1000, proposals: 4 };
        let (draws, _) = gibbs(&runs, &group, &[1.0], PRIOR_DF, settings, &mut rng);
        for target in 0..2 {
            let got = quantiles(&draws, target, 0);
            for (g, p) in got.iter().zip([0.05, 0.5, 0.95]) {
                let want = grid_quantile(&y, &[0.001; 5], &group, target, PRIOR_DF, p);
                assert!((g - want).abs() < 0.05, "current {target}, quantile {p}: {g} against {want}");
            }
        }
    }

    /// Runs with wide posteriors made under an informative prior p₀ =
    /// N(0, 0.5²): the layer must divide p₀ out. The runs' likelihoods are
    /// N(y_i, s_i²), so their posteriors under p₀ are normal with variance
    /// v_i = 1/(1/s_i² + 4) and mean v_i y_i/s_i², and the layer's answer is
    /// the grid's with y_i and s_i. Tolerance 0.06 on the 5, 50 and 95 %
    /// quantiles (about −1.4, 0.7, 2.76): over four seeds (the runs' 4000
    /// draws drawn afresh each time, 200 000 iterations) the quantiles
    /// scattered with sd at most 0.011: 0.06 is five Monte Carlo se.
    #[test]
    fn the_runs_prior_is_divided_out() {
        let y = [0.0, 0.5, 1.5];
        let s = [0.3, 0.4, 0.2];
        let mut rng = crate::rng::stream(12, &[1]);
        let runs: Vec<RunDraws> = y
            .iter()
            .zip(&s)
            .map(|(&y, &s)| {
                let v = 1.0 / (1.0 / (s * s) + 4.0);
                normal_draws(&[v * y / (s * s)], v.sqrt(), 4000, |z| -2.0 * z * z, &mut rng)
            })
            .collect();
        let settings = GibbsSettings { iterations: 200_000, burn_in: 1000, proposals: 8 };
        let (draws, acceptance) = gibbs(&runs, &[0, 0, 0], &[1.0], PRIOR_DF, settings, &mut rng);
        assert!(acceptance > 0.2, "acceptance {acceptance}");
        let got = quantiles(&draws, 0, 0);
        for (g, p) in got.iter().zip([0.05, 0.5, 0.95]) {
            let want = grid_quantile(&y, &s, &[0, 0, 0], 0, PRIOR_DF, p);
            assert!((g - want).abs() < 0.06, "quantile {p}: {g} against {want}");
        }
        // without dividing p₀ out, the layer would take the posteriors under
        // p₀ for the runs' likelihoods, closer to 0 and to each other: the
        // premise of the test is that this differs by more than the tolerance
        let (naive_y, naive_s): (Vec<f64>, Vec<f64>) = y.iter().zip(&s).map(|(&y, &s)| (y / (s * s) / (1.0 / (s * s) + 4.0), (1.0 / (1.0 / (s * s) + 4.0)).sqrt())).unzip();
        let gap = grid_quantile(&naive_y, &naive_s, &[0, 0, 0], 0, PRIOR_DF, 0.95) - grid_quantile(&y, &s, &[0, 0, 0], 0, PRIOR_DF, 0.95);
        assert!(gap.abs() > 0.15, "the premise: {gap}");
    }

    /// Two coordinates that move together between tests: precise runs on
    /// the line z₂ = z₁. The new test's correlation and sds against an
    /// independent computation: draws of (a, Σ) from the Huang-Wand prior,
    /// weighted by p(z | Σ) with the centre integrated out (∝ |Σ|^(−(m−1)/2)
    /// exp(−½ tr Σ⁻¹ S)), and the new test's covariance Σ(1 + 1/m) averaged
    /// over the weights. Tolerances: correlation 0.03, sds 5 % (the
    /// importance weights' effective sample size is a few thousand; the
    /// Gibbs draws' Monte Carlo error of the same size).
    #[test]
    fn correlated_spreads_are_learned() {
        let y = [[-1.0, -1.05], [0.0, 0.1], [1.0, 0.95], [0.4, 0.35]];
        let mut rng = crate::rng::stream(14, &[1]);
        let runs: Vec<RunDraws> = y.iter().map(|m| normal_draws(m, 0.001, 1000, |_| 0.0, &mut rng)).collect();
        let settings = GibbsSettings { iterations: 100_000, burn_in: 1000, proposals: 4 };
        let (draws, _) = gibbs(&runs, &[0, 0, 0, 0], &[1.0, 1.0], PRIOR_DF, settings, &mut rng);
        let moments = |v: &[[f64; 2]], w: &[f64]| {
            let total: f64 = w.iter().sum();
            let mean: [f64; 2] = std::array::from_fn(|k| v.iter().zip(w).map(|(x, w)| w * x[k]).sum::<f64>() / total);
            let cov = |a: usize, b: usize| v.iter().zip(w).map(|(x, w)| w * (x[a] - mean[a]) * (x[b] - mean[b])).sum::<f64>() / total;
            (cov(0, 0).sqrt(), cov(1, 1).sqrt(), cov(0, 1) / (cov(0, 0) * cov(1, 1)).sqrt())
        };
        let tests: Vec<[f64; 2]> = draws.iter().map(|d| [d.new_tests[0][0], d.new_tests[0][1]]).collect();
        let (s1, s2, r) = moments(&tests, &vec![1.0; tests.len()]);
        // the reference: prior draws weighted by the marginal likelihood
        let m = y.len() as f64;
        let centre: [f64; 2] = std::array::from_fn(|k| y.iter().map(|v| v[k]).sum::<f64>() / m);
        let scatter = DMatrix::from_fn(2, 2, |a, b| y.iter().map(|v| (v[a] - centre[a]) * (v[b] - centre[b])).sum::<f64>());
        let (mut w_sum, mut cov) = (0.0, DMatrix::<f64>::zeros(2, 2));
        let mut weights = Vec::new();
        let mut sigmas = Vec::new();
        for _ in 0..400_000 {
            let a: Vec<f64> = (0..2).map(|_| 1.0 / rng.sample::<f64, _>(Gamma::new(0.5, 1.0).unwrap())).collect();
            let psi = DMatrix::from_diagonal(&DVector::from_iterator(2, a.iter().map(|a| 2.0 * PRIOR_DF / a)));
            let sigma = inverse_wishart(&psi, PRIOR_DF + 1.0, &mut rng);
            let chol = Cholesky::new(sigma.clone()).unwrap();
            let log_det: f64 = chol.l().diagonal().iter().map(|v| 2.0 * v.ln()).sum();
            let log_w = -0.5 * (m - 1.0) * log_det - 0.5 * (chol.inverse() * &scatter).trace();
            weights.push(log_w);
            sigmas.push(sigma);
        }
        let top = weights.iter().cloned().fold(f64::MIN, f64::max);
        for (log_w, sigma) in weights.iter().zip(&sigmas) {
            let w = (log_w - top).exp();
            w_sum += w;
            cov += sigma * (w * (1.0 + 1.0 / m));
        }
        let cov = cov / w_sum;
        let want = (cov[(0, 0)].sqrt(), cov[(1, 1)].sqrt(), cov[(0, 1)] / (cov[(0, 0)] * cov[(1, 1)]).sqrt());
        // the premise: the runs lie on a line (correlation 0.99); the prior, with
        // four runs, tempers that, but not away
        assert!(want.2 > 0.5, "the premise: a strong correlation, {}", want.2);
        assert!((r - want.2).abs() < 0.03, "correlation {r} against {}", want.2);
        assert!((s1 / want.0 - 1.0).abs() < 0.05 && (s2 / want.1 - 1.0).abs() < 0.05, "sds {s1} {s2} against {want:?}");
    }
}
