//! The ensemble sampler on targets with known answers. Every tolerance is a
//! multiple of the Monte Carlo standard error, computed from the run's own
//! effective sample size; seeds are fixed.

use mrbp::sampler::diagnostics::{ess_bulk, ess_tail, quantile};
use mrbp::sampler::{
    Checkpointer, Diagnostics, Elliptical, LogDensity, Moments, Move, RunControl, Sampler,
    SamplerSettings,
};
use nalgebra::{DMatrix, DVector};

/// Tolerance in Monte Carlo standard errors: a correct sampler fails a single
/// check with probability ~6e-7 at 5 sd.
const Z: f64 = 5.0;

struct Gaussian {
    precision: DMatrix<f64>,
}

impl LogDensity for Gaussian {
    fn dim(&self) -> usize {
        self.precision.nrows()
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        let v = DVector::from_column_slice(x);
        -0.5 * (v.transpose() * &self.precision * &v)[(0, 0)]
    }
}

/// Σ = Q diag(λ) Qᵀ with λ log-spaced over [1, 1000] (condition number 1e3)
/// and Q a fixed rotation (QR of a seeded random matrix).
fn correlated_covariance(d: usize) -> DMatrix<f64> {
    use rand::RngExt;
    let mut rng = mrbp::rng::stream(5, &[]);
    let a = DMatrix::from_fn(d, d, |_, _| rng.random::<f64>() - 0.5);
    let q = a.qr().q();
    let lambda = DVector::from_fn(d, |i, _| 10f64.powf(3.0 * i as f64 / (d - 1) as f64));
    &q * DMatrix::from_diagonal(&lambda) * q.transpose()
}

fn start_ball(d: usize, chains: usize, center: &[f64], radius: f64) -> Vec<Vec<f64>> {
    use rand::RngExt;
    let mut rng = mrbp::rng::stream(77, &[]);
    (0..chains)
        .map(|_| (0..d).map(|i| center[i] + radius * (rng.random::<f64>() - 0.5)).collect())
        .collect()
}

fn pooled(traces: &[Vec<f64>]) -> Vec<f64> {
    traces.iter().flatten().copied().collect()
}

fn check_gaussian(moves: Vec<(Move, f64)>, steps: usize) {
    check_gaussian_with(moves, steps, None);
}

/// A reference distribution of `d` coordinates: `mean` for every
/// coordinate, covariance `cov`.
fn reference(mean: &[f64], cov: DMatrix<f64>) -> Elliptical {
    Elliptical::new(Moments { mean: DVector::from_column_slice(mean), cov }).unwrap()
}

/// [`check_gaussian`] with the sampler given a fixed `reference` for the
/// anchored move.
fn check_gaussian_with(moves: Vec<(Move, f64)>, steps: usize, reference: Option<Elliptical>) {
    let d = 10;
    let cov = correlated_covariance(d);
    let target = Gaussian { precision: cov.clone().try_inverse().unwrap() };
    let settings = SamplerSettings { walkers: 32, ensembles: 4, moves: moves.clone(), seed: 11 };
    let init = start_ball(d, 128, &vec![0.0; d], 1.0);
    let mut s = Sampler::new(&target, settings, &init).unwrap();
    if let Some(r) = reference {
        s = s.with_reference(r);
    }
    // run until converged (≥ 50 τ, R̂ < 1.01, τ stable), within a budget
    let control =
        RunControl { until_converged: true, check_every: 1000, ..RunControl::fixed(steps) };
    s.run(&control, &mut []).unwrap();
    check_zero_mean_moments(&s, &cov, &format!("{moves:?}"));
}

/// The sampler's converged chains have mean 0 and covariance `cov`, each
/// within [`Z`] Monte Carlo standard errors (`label` names the case).
fn check_zero_mean_moments<T: LogDensity>(s: &Sampler<T>, cov: &DMatrix<f64>, label: &str) {
    let d = cov.nrows();
    let diag = s.diagnostics();
    assert!(diag.converged(400.0), "{label}: {:?}", diag.warnings);
    let b = diag.burn_in;
    let traces: Vec<Vec<f64>> = (0..d).map(|i| pooled(&s.chains.traces(i, b))).collect();
    let n = traces[0].len() as f64;
    let ess_min = diag.coordinates.iter().map(|c| c.ess_bulk).fold(f64::INFINITY, f64::min);
    for i in 0..d {
        let c = &diag.coordinates[i];
        assert!(c.mean.abs() < Z * c.mcse_mean, "{label} mean {i}: {} ± {}", c.mean, c.mcse_mean);
        for j in 0..=i {
            let sij = traces[i].iter().zip(&traces[j]).map(|(a, b)| a * b).sum::<f64>() / n;
            // sd of a sample covariance of a Gaussian: √((Σii Σjj + Σij²)/ESS)
            let se = ((cov[(i, i)] * cov[(j, j)] + cov[(i, j)].powi(2)) / ess_min).sqrt();
            assert!(
                (sij - cov[(i, j)]).abs() < Z * se,
                "{label} cov {i},{j}: {sij} vs {}",
                cov[(i, j)]
            );
        }
    }
}

#[test]
fn correlated_gaussian_10d_stretch() {
    check_gaussian(vec![(Move::Stretch { a: 2.0 }, 1.0)], 20000);
}

#[test]
fn correlated_gaussian_10d_de_snooker_mixture() {
    check_gaussian(vec![(Move::differential_evolution(), 0.8), (Move::snooker(), 0.2)], 20000);
}

/// The calibration's default mixture: independence proposals fitted to the
/// complementary half, with a little DE.
#[test]
fn correlated_gaussian_10d_independence_mixture() {
    check_gaussian(vec![(Move::independence(), 0.9), (Move::differential_evolution(), 0.1)], 5000);
}

/// The calibration's default mixture: the independence move anchored on a
/// reference, here a poor one (each variance off by a factor 2 or 1/2 in
/// turn, the mean 0.5 sd off): the chain must stay exact whatever the
/// reference.
#[test]
fn correlated_gaussian_10d_anchored_mixture() {
    let d = 10;
    let cov = correlated_covariance(d);
    let scale = DVector::from_fn(d, |i, _| 2f64.powi(i as i32 % 3 - 1).sqrt());
    let wrong = DMatrix::from_diagonal(&scale) * &cov * DMatrix::from_diagonal(&scale);
    let mean: Vec<f64> = (0..d).map(|i| 0.5 * cov[(i, i)].sqrt()).collect();
    check_gaussian_with(
        vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)],
        5000,
        Some(reference(&mean, wrong)),
    );
}

/// The history move: a Student-t mixture fitted to each ensemble's past
/// steps, with a little DE.
#[test]
fn correlated_gaussian_10d_history_mixture() {
    check_gaussian(vec![(Move::history(), 0.9), (Move::differential_evolution(), 0.1)], 3000);
}

/// The curved move (a tube fitted to the complementary half, the half's
/// own Student-t, the anchored fit to a poor reference) on a Gaussian,
/// where the tube is an ellipsoid: exact whatever it fits.
#[test]
fn correlated_gaussian_10d_curved_mixture() {
    let d = 10;
    let cov = correlated_covariance(d);
    let mean: Vec<f64> = (0..d).map(|i| 0.5 * cov[(i, i)].sqrt()).collect();
    check_gaussian_with(
        vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)],
        5000,
        Some(reference(&mean, cov * 2.0)),
    );
}

/// x1 ~ N(1, 1), x2 | x1 ~ N(x1², 0.5²): a banana whose moments are known:
/// E x2 = 1 + 1 = 2, Var x2 = 0.25 + 4·1·1 + 2·1 = 6.25.
struct Banana;

impl LogDensity for Banana {
    fn dim(&self) -> usize {
        2
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        -0.5 * (x[0] - 1.0).powi(2) - 0.5 * ((x[1] - x[0] * x[0]) / 0.5).powi(2)
    }
}

#[test]
fn rosenbrock_banana_marginal_moments() {
    banana_moments(vec![(Move::Stretch { a: 2.0 }, 1.0)], 10000);
}

/// A Gaussian proposal fitted to a banana is a poor one: the mixture must
/// still be exact, only slower.
#[test]
fn rosenbrock_banana_with_independence_mixture() {
    banana_moments(vec![(Move::independence(), 0.7), (Move::differential_evolution(), 0.3)], 10000);
}

/// The history move on the banana: its mixture can follow the curve.
#[test]
fn rosenbrock_banana_with_history_mixture() {
    banana_moments(vec![(Move::history(), 0.8), (Move::differential_evolution(), 0.2)], 6000);
}

/// The anchored move on the banana, its reference a Gaussian at the mode
/// that knows nothing of the curve.
#[test]
fn rosenbrock_banana_with_anchored_mixture() {
    let r = reference(&[1.0, 1.0], DMatrix::from_diagonal(&DVector::from_vec(vec![1.0, 4.0])));
    banana_moments_with(
        vec![(Move::anchored(), 0.7), (Move::differential_evolution(), 0.3)],
        10000,
        Some(r),
    );
}

/// The curved move on the banana: its tube bends along x1.
#[test]
#[ignore = "slow tier: the curved move on a hard target (its 10-D Gaussian is in the fast tier)"]
fn rosenbrock_banana_with_curved_mixture() {
    banana_moments(vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)], 5000);
}

fn banana_moments(moves: Vec<(Move, f64)>, steps: usize) {
    banana_moments_with(moves, steps, None);
}

fn banana_moments_with(moves: Vec<(Move, f64)>, steps: usize, reference: Option<Elliptical>) {
    let settings = SamplerSettings { walkers: 32, ensembles: 4, moves, seed: 3 };
    let init = start_ball(2, 128, &[1.0, 1.0], 0.1);
    let mut s = Sampler::new(&Banana, settings, &init).unwrap();
    if let Some(r) = reference {
        s = s.with_reference(r);
    }
    s.run(&RunControl::fixed(steps), &mut []).unwrap();
    let diag = s.diagnostics();
    assert!(diag.converged(400.0), "{:?}", diag.warnings);
    let truth_mean = [1.0, 2.0];
    let truth_var = [1.0, 6.25];
    for i in 0..2 {
        let c = &diag.coordinates[i];
        assert!(
            (c.mean - truth_mean[i]).abs() < Z * c.mcse_mean,
            "mean {i}: {} ± {}",
            c.mean,
            c.mcse_mean
        );
        // MCSE of the variance: sd of (x − μ)² over √ESS of those squares
        let traces = s.chains.traces(i, diag.burn_in);
        let sq: Vec<Vec<f64>> = traces
            .iter()
            .map(|t| t.iter().map(|x| (x - truth_mean[i]).powi(2)).collect())
            .collect();
        let all = pooled(&sq);
        let m = all.iter().sum::<f64>() / all.len() as f64;
        let sd = (all.iter().map(|v| (v - m).powi(2)).sum::<f64>() / all.len() as f64).sqrt();
        let se = sd / ess_bulk(&sq).sqrt();
        assert!((m - truth_var[i]).abs() < Z * se, "var {i}: {m} vs {} (se {se})", truth_var[i]);
    }
}

/// A skewed target: x ~ LogNormal(0, 1) in 2-D (independent), sampled on
/// x > 0 directly. Its quantiles are exp(z_p).
struct LogNormal2;

impl LogDensity for LogNormal2 {
    fn dim(&self) -> usize {
        2
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        if x.iter().any(|v| *v <= 0.0) {
            return f64::NEG_INFINITY;
        }
        x.iter().map(|v| -v.ln() - 0.5 * v.ln().powi(2)).sum()
    }
}

#[test]
fn lognormal_quantiles() {
    let dist = statrs::distribution::LogNormal::new(0.0, 1.0).unwrap();
    check_quantiles(&LogNormal2, &dist, vec![(Move::Stretch { a: 2.0 }, 1.0)], 16, 5000);
}

#[test]
fn lognormal_quantiles_with_independence_mixture() {
    let dist = statrs::distribution::LogNormal::new(0.0, 1.0).unwrap();
    check_quantiles(
        &LogNormal2,
        &dist,
        vec![(Move::independence(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

#[test]
fn lognormal_quantiles_with_anchored_mixture() {
    let dist = statrs::distribution::LogNormal::new(0.0, 1.0).unwrap();
    let r = reference(&[1.0, 1.0], DMatrix::identity(2, 2));
    check_quantiles_with(
        &LogNormal2,
        &dist,
        vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
        Some(r),
    );
}

#[test]
#[ignore = "slow tier: the curved move on a hard target (its 10-D Gaussian is in the fast tier)"]
fn lognormal_quantiles_with_curved_mixture() {
    let dist = statrs::distribution::LogNormal::new(0.0, 1.0).unwrap();
    check_quantiles(
        &LogNormal2,
        &dist,
        vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

#[test]
fn lognormal_quantiles_with_history_mixture() {
    let dist = statrs::distribution::LogNormal::new(0.0, 1.0).unwrap();
    check_quantiles(
        &LogNormal2,
        &dist,
        vec![(Move::history(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

/// A target bounded by its prior: independent standard normals truncated
/// to x > 0.5 (most of the mass against the wall, as a posterior piled on
/// a prior bound); quantiles by the truncated normal's inverse CDF.
struct Truncated2;

impl LogDensity for Truncated2 {
    fn dim(&self) -> usize {
        2
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        if x.iter().any(|v| *v <= 0.5) {
            return f64::NEG_INFINITY;
        }
        x.iter().map(|v| -0.5 * v * v).sum()
    }
}

/// N(0, 1) truncated to (0.5, ∞).
struct TruncatedNormal;

impl TruncatedNormal {
    fn mass() -> f64 {
        use statrs::distribution::ContinuousCDF;
        1.0 - statrs::distribution::Normal::standard().cdf(0.5)
    }
}

impl statrs::distribution::Continuous<f64, f64> for TruncatedNormal {
    fn pdf(&self, x: f64) -> f64 {
        if x <= 0.5 {
            0.0
        } else {
            (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt() / Self::mass()
        }
    }
    fn ln_pdf(&self, x: f64) -> f64 {
        self.pdf(x).ln()
    }
}

impl statrs::statistics::Min<f64> for TruncatedNormal {
    fn min(&self) -> f64 {
        0.5
    }
}

impl statrs::statistics::Max<f64> for TruncatedNormal {
    fn max(&self) -> f64 {
        f64::INFINITY
    }
}

impl statrs::distribution::ContinuousCDF<f64, f64> for TruncatedNormal {
    fn cdf(&self, x: f64) -> f64 {
        let n = statrs::distribution::Normal::standard();
        if x <= 0.5 {
            0.0
        } else {
            (n.cdf(x) - n.cdf(0.5)) / Self::mass()
        }
    }
    fn inverse_cdf(&self, p: f64) -> f64 {
        let n = statrs::distribution::Normal::standard();
        n.inverse_cdf(n.cdf(0.5) + p * Self::mass())
    }
}

#[test]
fn truncated_quantiles_with_independence_mixture() {
    check_quantiles(
        &Truncated2,
        &TruncatedNormal,
        vec![(Move::independence(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

#[test]
fn truncated_quantiles_with_anchored_mixture() {
    let r = reference(&[0.9, 0.9], DMatrix::identity(2, 2) * 0.25);
    check_quantiles_with(
        &Truncated2,
        &TruncatedNormal,
        vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
        Some(r),
    );
}

#[test]
#[ignore = "slow tier: the curved move on a hard target (its 10-D Gaussian is in the fast tier)"]
fn truncated_quantiles_with_curved_mixture() {
    check_quantiles(
        &Truncated2,
        &TruncatedNormal,
        vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

#[test]
fn truncated_quantiles_with_history_mixture() {
    check_quantiles(
        &Truncated2,
        &TruncatedNormal,
        vec![(Move::history(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

#[test]
fn heavy_tailed_quantiles_with_history_mixture() {
    let dist = statrs::distribution::StudentsT::new(0.0, 1.0, 3.0).unwrap();
    check_quantiles(
        &StudentT2,
        &dist,
        vec![(Move::history(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

/// A heavy-tailed target: independent Student-t coordinates with ν = 3 in
/// 2-D, whose tails are far heavier than the ν = 10 proposals of the
/// independence move; quantiles are those of the t distribution.
struct StudentT2;

impl LogDensity for StudentT2 {
    fn dim(&self) -> usize {
        2
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        x.iter().map(|v| -2.0 * (1.0 + v * v / 3.0).ln()).sum()
    }
}

#[test]
fn heavy_tailed_quantiles_with_anchored_mixture() {
    let dist = statrs::distribution::StudentsT::new(0.0, 1.0, 3.0).unwrap();
    let r = reference(&[0.0, 0.0], DMatrix::identity(2, 2));
    check_quantiles_with(
        &StudentT2,
        &dist,
        vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
        Some(r),
    );
}

#[test]
#[ignore = "slow tier: the curved move on a hard target (its 10-D Gaussian is in the fast tier)"]
fn heavy_tailed_quantiles_with_curved_mixture() {
    let dist = statrs::distribution::StudentsT::new(0.0, 1.0, 3.0).unwrap();
    check_quantiles(
        &StudentT2,
        &dist,
        vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

#[test]
fn heavy_tailed_quantiles_with_independence_mixture() {
    let dist = statrs::distribution::StudentsT::new(0.0, 1.0, 3.0).unwrap();
    check_quantiles(
        &StudentT2,
        &dist,
        vec![(Move::independence(), 0.9), (Move::differential_evolution(), 0.1)],
        32,
        3000,
    );
}

/// Runs `steps` steps of 4 ensembles of `walkers` and compares the 5, 50
/// and 95 % quantiles of each coordinate with those of `dist`.
fn check_quantiles<D>(
    target: &impl LogDensity,
    dist: &D,
    moves: Vec<(Move, f64)>,
    walkers: usize,
    steps: usize,
) where
    D: statrs::distribution::Continuous<f64, f64> + statrs::distribution::ContinuousCDF<f64, f64>,
{
    check_quantiles_with(target, dist, moves, walkers, steps, None);
}

/// [`check_quantiles`] with a fixed `reference` for the anchored move.
fn check_quantiles_with<D>(
    target: &impl LogDensity,
    dist: &D,
    moves: Vec<(Move, f64)>,
    walkers: usize,
    steps: usize,
    reference: Option<Elliptical>,
) where
    D: statrs::distribution::Continuous<f64, f64> + statrs::distribution::ContinuousCDF<f64, f64>,
{
    let settings = SamplerSettings { walkers, ensembles: 4, moves: moves.clone(), seed: 8 };
    let init = start_ball(2, 4 * walkers, &[1.0, 1.0], 0.2);
    let mut s = Sampler::new(target, settings, &init).unwrap();
    if let Some(r) = reference {
        s = s.with_reference(r);
    }
    s.run(&RunControl::fixed(steps), &mut []).unwrap();
    let diag = s.diagnostics();
    assert!(diag.converged(400.0), "{moves:?}: {:?}", diag.warnings);
    for i in 0..2 {
        let traces = s.chains.traces(i, diag.burn_in);
        let all = pooled(&traces);
        let ess = ess_tail(&traces).min(ess_bulk(&traces));
        for p in [0.05, 0.5, 0.95] {
            let q = dist.inverse_cdf(p);
            // asymptotic sd of a sample quantile: √(p(1−p)/ESS) / f(q)
            let se = (p * (1.0 - p) / ess).sqrt() / dist.pdf(q);
            let est = quantile(&all, p);
            assert!((est - q).abs() < Z * se, "{moves:?} x{i} q{p}: {est} vs {q} (se {se})");
        }
    }
}

fn small_run(threads: usize, steps: usize) -> Vec<f64> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let settings = SamplerSettings {
            walkers: 8,
            ensembles: 3,
            moves: vec![
                (Move::Stretch { a: 2.0 }, 0.3),
                (Move::differential_evolution(), 0.2),
                (Move::snooker(), 0.2),
                (Move::independence(), 0.1),
                (Move::history(), 0.1),
                (Move::anchored(), 0.1),
            ],
            seed: 42,
        };
        let init = start_ball(2, 24, &[1.0, 1.0], 0.1);
        let mut s = Sampler::new(&Banana, settings, &init)
            .unwrap()
            .with_reference(reference(&[1.0, 1.0], DMatrix::identity(2, 2)));
        s.run(&RunControl::fixed(steps), &mut []).unwrap();
        s.chains.positions.clone()
    })
}

#[test]
fn same_seed_same_chains_whatever_the_thread_count() {
    let one = small_run(1, 300);
    let two = small_run(2, 300);
    let four = small_run(4, 300);
    assert_eq!(one.len(), 301 * 24 * 2);
    assert!(one.iter().zip(&two).all(|(a, b)| a.to_bits() == b.to_bits()));
    assert!(one.iter().zip(&four).all(|(a, b)| a.to_bits() == b.to_bits()));
}

/// A run that confirms stops at the first check from twice the step at
/// which the rule first held, and a run interrupted between the two and
/// resumed stops at the same step with the same chains (the checks before
/// the interruption are made again on the chains as they were).
#[test]
fn a_confirming_run_doubles_and_resumes_where_it_would_have_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let cp = dir.path().join("state.bin");
    let settings = SamplerSettings {
        walkers: 16,
        ensembles: 4,
        moves: vec![(Move::Stretch { a: 2.0 }, 0.8), (Move::differential_evolution(), 0.2)],
        seed: 5,
    };
    let target = Gaussian { precision: correlated_covariance(3).try_inverse().unwrap() };
    let init = start_ball(3, 64, &[0.0; 3], 0.1);
    let control = RunControl {
        until_converged: true,
        check_every: 10,
        min_ess: 200.0,
        ..RunControl::fixed(5000)
    };
    let mut plain = Sampler::new(&target, settings.clone(), &init).unwrap();
    plain.run(&control, &mut []).unwrap();
    let first = plain.chains.steps() - 1;
    let confirming = RunControl { confirm: true, ..control.clone() };
    let mut whole = Sampler::new(&target, settings.clone(), &init).unwrap();
    whole.run(&confirming, &mut []).unwrap();
    let stopped = whole.chains.steps() - 1;
    let next_check = (2 * first..).find(|s| confirming.checks_at(*s)).unwrap();
    assert!(stopped >= 2 * first, "stopped at {stopped}, first held at {first}");
    // here the rule holds again at the first check from there
    assert_eq!(stopped, next_check, "first held at {first}");
    // "killed" between the two: only the checkpoint survives
    let killed = first + (stopped - first) / 2;
    {
        let mut run = Sampler::new(&target, settings, &init).unwrap();
        let mut saver = Checkpointer { path: cp.clone(), every: 1000, stop: || false };
        run.run(&RunControl::fixed(killed), &mut [&mut saver]).unwrap();
    }
    let mut resumed = Sampler::resume(&target, &cp).unwrap();
    resumed.run(&confirming, &mut []).unwrap();
    assert_eq!(resumed.chains.steps() - 1, stopped);
    assert!(resumed.chains == whole.chains, "the resumed run differs");
}

#[test]
fn resumed_run_equals_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let cp = dir.path().join("state.bin");
    let settings = SamplerSettings {
        walkers: 8,
        ensembles: 2,
        // the history move refits at 64 from the checkpoint's chains, then at 128
        moves: vec![
            (Move::Stretch { a: 2.0 }, 0.5),
            (Move::snooker(), 0.2),
            (Move::history(), 0.3),
        ],
        seed: 9,
    };
    let init = start_ball(2, 16, &[1.0, 1.0], 0.1);

    let mut whole = Sampler::new(&Banana, settings.clone(), &init).unwrap();
    whole.run(&RunControl::fixed(200), &mut []).unwrap();

    // "killed" after step 120: only the checkpoint file survives
    {
        let mut first = Sampler::new(&Banana, settings, &init).unwrap();
        let mut saver = Checkpointer { path: cp.clone(), every: 40, stop: || false };
        first.run(&RunControl::fixed(120), &mut [&mut saver]).unwrap();
    }
    let mut resumed = Sampler::resume(&Banana, &cp).unwrap();
    assert_eq!(resumed.chains.steps(), 121);
    resumed.run(&RunControl::fixed(200), &mut []).unwrap();
    assert_eq!(resumed.chains, whole.chains);
}

#[test]
fn refuses_to_start_at_minus_infinity_and_names_the_walker() {
    let settings = SamplerSettings { walkers: 4, ensembles: 2, ..SamplerSettings::default() };
    let mut init = start_ball(2, 8, &[1.0, 1.0], 0.1);
    init[5] = vec![-1.0, 1.0];
    let err = Sampler::new(&LogNormal2, settings, &init).err().unwrap().to_string();
    assert!(err.contains("walker 5 (ensemble 1, walker 1)"), "{err}");
}

#[test]
fn stuck_walker_is_detected() {
    // a walker frozen at its start: acceptance 0
    let settings = SamplerSettings { walkers: 8, ensembles: 1, ..SamplerSettings::default() };
    let init = start_ball(2, 8, &[1.0, 1.0], 0.1);
    let mut s = Sampler::new(&Banana, settings, &init).unwrap();
    s.run(&RunControl::fixed(200), &mut []).unwrap();
    let nc = s.chains.chains();
    for step in 0..s.chains.steps() {
        s.chains.accepted[step * nc + 3] = false;
    }
    let diag = Diagnostics::compute(&s.chains, 50);
    assert_eq!(diag.stuck, vec![3]);
    assert!(diag.warnings.iter().any(|w| w.contains("stuck")));
}

/// A run whose proposals are rarely accepted is flagged (whatever R̂ and ESS
/// say); the same run as sampled, accepting about a third, is not.
#[test]
fn rarely_accepted_proposals_are_flagged() {
    let settings = SamplerSettings { walkers: 16, ensembles: 2, ..SamplerSettings::default() };
    let init = start_ball(2, 32, &[1.0, 1.0], 0.1);
    let mut s = Sampler::new(&Banana, settings, &init).unwrap();
    s.run(&RunControl::fixed(300), &mut []).unwrap();
    let flagged = |d: &Diagnostics| {
        d.warnings.iter().any(|w| w.contains("proposals were accepted at a median rate"))
    };
    let diag = Diagnostics::compute(&s.chains, 50);
    assert!(
        !flagged(&diag)
            && diag.acceptance.iter().sum::<f64>() / 32.0
                > mrbp::sampler::diagnostics::LOW_ACCEPTANCE,
        "{:?}",
        diag.warnings
    );
    // keep one accepted proposal in twenty (the positions are left as they
    // are: the diagnostic reads the acceptance record only)
    let nc = s.chains.chains();
    for step in 0..s.chains.steps() {
        for c in 0..nc {
            if (step + c) % 20 != 0 {
                s.chains.accepted[step * nc + c] = false;
            }
        }
    }
    let diag = Diagnostics::compute(&s.chains, 50);
    assert!(flagged(&diag), "{:?}", diag.warnings);
}

/// Two unit normals in 3-d, centred at 0 and at (20, 20, 20) with weight
/// e^−`minor` (log-density: the log of their sum; a barrier of over 100
/// nats between them).
struct TwoModes {
    minor: f64,
}

impl LogDensity for TwoModes {
    fn dim(&self) -> usize {
        3
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        let a = -0.5 * x.iter().map(|v| v * v).sum::<f64>();
        let b = -self.minor - 0.5 * x.iter().map(|v| (v - 20.0).powi(2)).sum::<f64>();
        a.max(b) + (-(a - b).abs()).exp().ln_1p()
    }
}

/// Ensembles 2 and 3 start in the mode with e^−40 of the mass, which no
/// move leaves: at step 32 they are drawn afresh from ensemble 0's or 1's
/// spread, and the run converges on the main mode (mean 0 within 5 MCSE,
/// R̂ < 1.01); the burn-in starts after the redraw and the redraws are the
/// ones replayed from the chains. With equal modes the split start is left
/// alone (no redraw: each ensemble holds half the mass) and R̂ says so.
#[test]
fn an_ensemble_stranded_in_a_negligible_mode_is_drawn_afresh() {
    use mrbp::sampler::stranded;
    let start = |chains: usize| -> Vec<Vec<f64>> {
        let low = start_ball(3, chains / 2, &[0.0; 3], 1.0);
        let high = start_ball(3, chains / 2, &[20.0; 3], 1.0);
        low.into_iter().chain(high).collect()
    };
    let settings = SamplerSettings {
        walkers: 32,
        ensembles: 4,
        moves: vec![(Move::differential_evolution(), 0.8), (Move::snooker(), 0.2)],
        seed: 3,
    };
    let target = TwoModes { minor: 40.0 };
    let mut s = Sampler::new(&target, settings.clone(), &start(128)).unwrap();
    s.run(
        &RunControl {
            until_converged: true,
            check_every: 100,
            min_ess: 400.0,
            ..RunControl::fixed(4000)
        },
        &mut [],
    )
    .unwrap();
    let redraws = stranded::history(&s.chains);
    assert_eq!(
        redraws.iter().map(|r| (r.step, r.ensemble)).collect::<Vec<_>>(),
        vec![(32, 2), (32, 3)],
        "{redraws:?}"
    );
    assert!(redraws.iter().all(|r| r.from < 2 && (r.gap - 40.0).abs() < 5.0), "{redraws:?}");
    let diag = s.diagnostics();
    assert!(diag.burn_in >= 32, "burn-in {}", diag.burn_in);
    assert!(diag.converged(400.0), "{:?}", diag.warnings);
    for c in &diag.coordinates {
        assert!(c.mean.abs() < Z * c.mcse_mean, "mean {} ± {}", c.mean, c.mcse_mean);
    }

    let equal = TwoModes { minor: 0.0 };
    let mut s = Sampler::new(&equal, settings, &start(128)).unwrap();
    s.run(&RunControl::fixed(300), &mut []).unwrap();
    assert!(stranded::history(&s.chains).is_empty());
    assert!(
        s.diagnostics().max_rhat() > 1.5,
        "two modes, one per half of the ensembles: R̂ must say so"
    );
}

/// A curved ridge with a long, thin end in six dimensions: x0 Gumbel
/// (ln p = −x0 − e^(−x0): a short lower and a long upper tail), x1 | x0 ~
/// N(0.3 x0², 0.05²) (the ridge bends, and its far end lies where few
/// walkers are), x2…x5 standard normal. The shape of the measured
/// `I1.00_25mm_0.25Hz` posterior's m1 end, with a known answer.
struct SkewedRidge;

impl LogDensity for SkewedRidge {
    fn dim(&self) -> usize {
        6
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        let r = (x[1] - 0.3 * x[0] * x[0]) / 0.05;
        -x[0] - (-x[0]).exp() - 0.5 * r * r - 0.5 * x[2..].iter().map(|v| v * v).sum::<f64>()
    }
}

/// The curved move's quantiles of x0 on [`SkewedRidge`], the far end's
/// included (Gumbel quantiles −ln(−ln p)), within [`Z`] standard errors
/// from the bulk and tail ESS, in a run that stops by the calibration's
/// rule for posteriors far from Gaussian (R̂, ESS and 10 τ, then on to
/// twice that step: `RunControl::confirm`), started in a small ball at the
/// mode as a calibration starts. Over seeds 1–16 the rule first held at
/// steps 260–400, where the 95 % quantile averaged 2.32 (truth 2.970: a
/// run stopped there would put 90.5 % of the mass below its "95 %"
/// quantile); at twice that step 2.88 ± 0.09 (94.5 %), at 100 τ
/// (960–1280 steps) 2.96 (docs/performance.md, "Stopping far from the
/// Laplace approximation").
#[test]
#[ignore = "slow tier: the curved move on a hard target (its 10-D Gaussian is in the fast tier)"]
fn skewed_ridge_quantiles_with_curved_mixture() {
    let settings = SamplerSettings {
        walkers: 64,
        ensembles: 4,
        moves: vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)],
        seed: 8,
    };
    let init: Vec<Vec<f64>> = start_ball(6, 256, &[0.0; 6], 0.05)
        .into_iter()
        .map(|mut x| {
            x[1] = 0.3 * x[0] * x[0];
            x
        })
        .collect();
    let mut s = Sampler::new(&SkewedRidge, settings, &init).unwrap();
    let control = RunControl {
        until_converged: true,
        check_every: 10,
        min_ess: 400.0,
        confirm: true,
        ..RunControl::fixed(5000)
    };
    s.run(&control, &mut []).unwrap();
    let diag = s.diagnostics();
    assert!(diag.converged(400.0), "{:?}", diag.warnings);
    let traces = s.chains.traces(0, diag.burn_in);
    let all = pooled(&traces);
    let ess = ess_tail(&traces).min(ess_bulk(&traces));
    for p in [0.05_f64, 0.5, 0.95, 0.99] {
        let q = -(-p.ln()).ln();
        let density = (-q - (-q).exp()).exp();
        let se = (p * (1.0 - p) / ess).sqrt() / density;
        let est = quantile(&all, p);
        assert!((est - q).abs() < Z * se, "q{p}: {est} vs {q} (se {se})");
    }
}

/// A correlated Gaussian whose last coordinates are also updated in blocks
/// on their own ([`LogDensity::blocks`]): blocks {3, 4} and {5}, which do
/// not interact (their precision entries are 0), each coupled to the rest.
/// A block's terms g_b = −½ x_bᵀ P_bb x_b − x_bᵀ P_br x_r are computed
/// with x_r from the memo alone (the point of the last full evaluation),
/// so a memo of the wrong point would bias the draws.
struct BlockedGaussian {
    inner: Gaussian,
}

const REST: [usize; 3] = [0, 1, 2];

impl BlockedGaussian {
    fn term(&self, b: usize, x: &[f64], rest: &[f64]) -> f64 {
        let p = &self.inner.precision;
        let block = &self.blocks()[b];
        let mut g = 0.0;
        for &i in block {
            for &j in block {
                g -= 0.5 * x[i] * p[(i, j)] * x[j];
            }
            for &j in &REST {
                g -= x[i] * p[(i, j)] * rest[j];
            }
        }
        g
    }
}

impl LogDensity for BlockedGaussian {
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        self.inner.log_density(x)
    }
    fn blocks(&self) -> Vec<Vec<usize>> {
        vec![vec![3, 4], vec![5]]
    }
    fn log_density_batch_memo(&self, xs: &[f64], out: &mut [f64], memos: &mut [Vec<f64>]) {
        let d = self.dim();
        for ((x, o), m) in xs.chunks(d).zip(out.iter_mut()).zip(memos.iter_mut()) {
            *o = self.log_density(x);
            m.clear();
            m.extend([self.term(0, x, x), self.term(1, x, x)]);
            m.extend_from_slice(x);
        }
    }
    fn block_log_density_batch(&self, b: usize, xs: &[f64], memos: &[&[f64]], out: &mut [f64]) {
        let d = self.dim();
        for ((x, o), m) in xs.chunks(d).zip(out.iter_mut()).zip(memos) {
            *o = self.term(b, x, &m[2..]);
        }
    }
}

fn blocked_gaussian() -> (BlockedGaussian, DMatrix<f64>) {
    let mut precision = correlated_covariance(6).try_inverse().unwrap();
    for (i, j) in [(3, 5), (4, 5), (5, 3), (5, 4)] {
        precision[(i, j)] = 0.0;
    }
    // kept positive definite
    precision += DMatrix::identity(6, 6);
    let cov = precision.clone().try_inverse().unwrap();
    assert!(cov.clone().cholesky().is_some(), "a covariance");
    (BlockedGaussian { inner: Gaussian { precision } }, cov)
}

/// The block updates leave the target invariant: means and covariances of
/// a correlated Gaussian within [`Z`] Monte Carlo standard errors.
#[test]
fn block_updates_keep_a_correlated_gaussian() {
    let (target, cov) = blocked_gaussian();
    let d = 6;
    let settings = SamplerSettings {
        walkers: 24,
        ensembles: 4,
        moves: vec![(Move::Stretch { a: 2.0 }, 1.0)],
        seed: 13,
    };
    let init = start_ball(d, 96, &vec![0.0; d], 1.0);
    let mut s = Sampler::new(&target, settings, &init).unwrap();
    let control =
        RunControl { until_converged: true, check_every: 1000, ..RunControl::fixed(20000) };
    s.run(&control, &mut []).unwrap();
    check_zero_mean_moments(&s, &cov, "blocks");
    // the stored log-densities are the target's at the stored positions
    let last = s.chains.steps() - 1;
    for c in 0..s.chains.chains() {
        let lp = s.chains.log_prob[last * s.chains.chains() + c];
        assert!((lp - target.log_density(s.chains.point(last, c))).abs() < 1e-9 * (1.0 + lp.abs()));
    }
}

/// With block updates too, the chains do not depend on the thread count,
/// and a resumed run (whose memos are remade) equals an uninterrupted one.
#[test]
fn block_updates_are_reproducible_and_resumable() {
    let (target, _) = blocked_gaussian();
    let settings = SamplerSettings {
        walkers: 12,
        ensembles: 2,
        moves: vec![(Move::Stretch { a: 2.0 }, 0.7), (Move::independence(), 0.3)],
        seed: 4,
    };
    let init = start_ball(6, 24, &[0.0; 6], 1.0);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut s = Sampler::new(&target, settings.clone(), &init).unwrap();
            s.run(&RunControl::fixed(150), &mut []).unwrap();
            s.chains
        })
    };
    let one = run(1);
    assert!(one == run(2), "the chains depend on the thread count");
    let dir = tempfile::tempdir().unwrap();
    let cp = dir.path().join("state.bin");
    {
        let mut first = Sampler::new(&target, settings.clone(), &init).unwrap();
        let mut saver = Checkpointer { path: cp.clone(), every: 40, stop: || false };
        first.run(&RunControl::fixed(80), &mut [&mut saver]).unwrap();
    }
    let mut resumed = Sampler::resume(&target, &cp).unwrap();
    resumed.run(&RunControl::fixed(150), &mut []).unwrap();
    assert!(resumed.chains == one, "the resumed run differs");
}

/// The drift test's false alarms on draws that are stationary from the
/// first step: walkers started as exact draws of the 10-D correlated
/// Gaussian, with the calibration's default moves (anchored on the target
/// itself, and DE) and with the stretch move. The walkers of an ensemble
/// share their proposals, so their means and spreads vary together more
/// than independent chains' would; the test's threshold of 4 standard
/// errors must leave room for that. Windows of 40–300 steps after
/// burn-ins of 0 to half the window (133 a move set, every coordinate,
/// both moments): at most 1 % find a drift. Measured over nine seeds
/// (2 394 windows): one did (a spread, z −4.09, stretch move); the
/// largest |z| of a seed 2.1–3.8 for the mean, 2.5–3.6 for the spread.
/// A false alarm costs a run a check's steps, not its draws.
#[test]
fn stationary_ensembles_show_no_drift() {
    use mrbp::sampler::drift::{drift, statistics, Moment};
    use rand::RngExt;
    let d = 10;
    let cov = correlated_covariance(d);
    let target = Gaussian { precision: cov.clone().try_inverse().unwrap() };
    let chol = cov.clone().cholesky().unwrap().l();
    let mut rng = mrbp::rng::stream(31, &[]);
    let init: Vec<Vec<f64>> = (0..128)
        .map(|_| {
            let e = DVector::from_fn(d, |_, _| rng.sample::<f64, _>(rand_distr::StandardNormal));
            (&chol * e).iter().copied().collect()
        })
        .collect();
    let (mut worst, mut windows, mut alarms) = (Vec::new(), 0, Vec::new());
    for (label, moves) in [
        ("anchored", vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)]),
        ("stretch", vec![(Move::default(), 1.0)]),
    ] {
        let settings = SamplerSettings { walkers: 32, ensembles: 4, moves, seed: 12 };
        let mut s = Sampler::new(&target, settings, &init)
            .unwrap()
            .with_reference(reference(&vec![0.0; d], cov.clone()));
        s.run(&RunControl::fixed(300), &mut []).unwrap();
        let c = &s.chains;
        let mut largest = [0.0f64; 2];
        for end in (40..=300).step_by(20) {
            let head = c.first_steps(end);
            for burn_in in (0..=end / 2).step_by(10) {
                windows += 1;
                if let Some(found) = drift(&head, burn_in) {
                    alarms.push((label, burn_in, end, found));
                }
                for found in statistics(&head, burn_in) {
                    let k = usize::from(found.moment == Moment::Spread);
                    largest[k] = largest[k].max(found.z.abs());
                }
            }
        }
        worst.push((label, largest));
    }
    eprintln!("largest |z| (mean, spread): {worst:?}");
    assert_eq!(windows, 266);
    assert!(alarms.len() <= windows / 100, "drifts in stationary draws: {alarms:?}");
}
