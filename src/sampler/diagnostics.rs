//! Convergence diagnostics of MCMC chains.
//!
//! * integrated autocorrelation time τ with Sokal's automatic window, on the
//!   walker-averaged autocorrelation function (as emcee does);
//! * rank-normalised split R̂, bulk and tail ESS (Vehtari, Gelman, Simpson,
//!   Carpenter & Bürkner 2021), with Geyer's initial monotone sequence;
//! * Monte Carlo standard error of the mean; acceptance and stuck walkers;
//! * draws that still drift after burn-in ([`super::drift`]), which move
//!   the burn-in past the drift.
//!
//! Every function takes chains as `[chain][draw]`.

use rayon::prelude::*;
use rustfft::{num_complex::Complex, FftPlanner};

use super::chains::Chains;
use super::drift::{drift, past_drift, Drift, Moment, DRIFT_Z};
use crate::numeric::{mean, rank_normalize, variance};

/// Sokal's window constant: the sum runs to the first lag M ≥ C τ(M).
const SOKAL_C: f64 = 5.0;
/// A chain should be at least this many τ long after burn-in to trust its
/// estimates of τ and ESS (with many walkers the autocorrelation is averaged
/// over all of them, so fewer τ suffice than for one chain).
pub const MIN_TAU_MULTIPLE: f64 = 10.0;
/// R̂ threshold of Vehtari et al. (2021).
pub const RHAT_THRESHOLD: f64 = 1.01;
/// Burn-in is this many τ, at most half the chain.
const BURN_IN_TAUS: f64 = 3.0;
/// A walker is stuck when so few of its proposals were accepted that a
/// walker accepting at the median rate would do so with probability below
/// this, divided by the number of walkers.
const STUCK_P: f64 = 1e-3;

/// Below this median acceptance rate (per walker and step, after burn-in)
/// the moves propose far from where the posterior is: typical calibrations
/// accept 0.25–0.5 of their proposals (the measured records alone, the
/// joint calibrations, the virtual campaigns), a Gaussian random walk
/// tuned for many dimensions about 0.23. On the measured 1 A 25 mm /
/// 0.25 Hz record alone the default moves accepted 0.066 and passed R̂ and
/// ESS while a tail held 8 % of the draws where a long run puts 12 %
/// (docs/performance.md, "The samplers disagree there").
pub const LOW_ACCEPTANCE: f64 = 0.1;

/// The normalised autocorrelation function of one series, by FFT.
pub fn autocorrelation(x: &[f64]) -> Vec<f64> {
    let acov = autocovariance(x);
    let c0 = acov[0];
    if c0 > 0.0 {
        acov.iter().map(|c| c / c0).collect()
    } else {
        let mut r = vec![0.0; x.len()];
        r[0] = 1.0;
        r
    }
}

thread_local! {
    /// FFT plans are costly to make and reused across the many chains.
    static PLANNER: std::cell::RefCell<FftPlanner<f64>> = std::cell::RefCell::new(FftPlanner::new());
}

/// Biased autocovariance (divided by n) at lags 0..n, by zero-padded FFT.
pub fn autocovariance(x: &[f64]) -> Vec<f64> {
    let n = x.len();
    if n == 0 {
        return vec![];
    }
    let mean = x.iter().sum::<f64>() / n as f64;
    let size = (2 * n).next_power_of_two();
    let mut buf: Vec<Complex<f64>> = x
        .iter()
        .map(|v| Complex::new(v - mean, 0.0))
        .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
        .take(size)
        .collect();
    PLANNER.with(|planner| {
        let mut planner = planner.borrow_mut();
        planner.plan_fft_forward(size).process(&mut buf);
        for z in buf.iter_mut() {
            *z = Complex::new(z.norm_sqr(), 0.0);
        }
        planner.plan_fft_inverse(size).process(&mut buf);
    });
    buf[..n].iter().map(|z| z.re / (size as f64 * n as f64)).collect()
}

/// Integrated autocorrelation time of a set of chains of one quantity: the
/// autocorrelation functions are averaged over chains, then summed up to
/// Sokal's automatic window.
pub fn integrated_time(chains: &[Vec<f64>]) -> f64 {
    let n = chains.iter().map(Vec::len).min().unwrap_or(0);
    if n < 2 {
        return f64::NAN;
    }
    let mut rho = vec![0.0; n];
    for c in chains {
        for (r, a) in rho.iter_mut().zip(autocorrelation(&c[..n])) {
            *r += a / chains.len() as f64;
        }
    }
    let mut tau = 1.0;
    for (m, r) in rho.iter().enumerate().skip(1) {
        tau += 2.0 * r;
        if m as f64 >= SOKAL_C * tau {
            return tau.max(1.0);
        }
    }
    tau.max(1.0)
}

/// Each chain cut in two halves (the middle draw dropped when odd).
fn split(chains: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = chains.iter().map(Vec::len).min().unwrap_or(0) / 2;
    chains.iter().flat_map(|c| [c[..n].to_vec(), c[c.len() - n..].to_vec()]).collect()
}

/// Classic potential scale reduction of equal-length chains.
fn rhat_basic(chains: &[Vec<f64>]) -> f64 {
    let n = chains[0].len() as f64;
    let means: Vec<f64> = chains.iter().map(|c| mean(c)).collect();
    let w = mean(&chains.iter().map(|c| variance(c)).collect::<Vec<_>>());
    let b = n * variance(&means);
    let var_plus = (n - 1.0) / n * w + b / n;
    if w > 0.0 {
        (var_plus / w).sqrt()
    } else {
        f64::NAN
    }
}

/// |x − median of all draws|: the folded draws whose R̂ detects a
/// difference in scale (tails) between chains.
fn folded(chains: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let med = quantile(&pool(chains), 0.5);
    chains.iter().map(|c| c.iter().map(|x| (x - med).abs()).collect()).collect()
}

/// Rank-normalised split R̂: the larger of the bulk and the folded (tail) R̂.
pub fn split_rhat(chains: &[Vec<f64>]) -> f64 {
    rhat_of_normalized(&rank_normalize(chains), &rank_normalize(&folded(chains)))
}

fn rhat_of_normalized(z: &[Vec<f64>], z_folded: &[Vec<f64>]) -> f64 {
    let s = split(z);
    if s.is_empty() || s[0].len() < 2 {
        return f64::NAN;
    }
    rhat_basic(&s).max(rhat_basic(&split(z_folded)))
}

/// Effective sample size of equal-length chains (Geyer's initial monotone
/// sequence on the multi-chain autocorrelation, as in Stan).
pub fn ess(chains: &[Vec<f64>]) -> f64 {
    let m = chains.len();
    let n = chains.iter().map(Vec::len).min().unwrap_or(0);
    if m == 0 || n < 4 {
        return f64::NAN;
    }
    let acov: Vec<Vec<f64>> = chains.iter().map(|c| autocovariance(&c[..n])).collect();
    let nf = n as f64;
    let chain_means: Vec<f64> = chains.iter().map(|c| mean(&c[..n])).collect();
    let mean_var = acov.iter().map(|a| a[0] * nf / (nf - 1.0)).sum::<f64>() / m as f64;
    let mut var_plus = mean_var * (nf - 1.0) / nf;
    if m > 1 {
        var_plus += variance(&chain_means);
    }
    if !(var_plus > 0.0) {
        return f64::NAN;
    }
    let rho =
        |t: usize| 1.0 - (mean_var - acov.iter().map(|a| a[t]).sum::<f64>() / m as f64) / var_plus;
    // Geyer's initial positive sequence: pairs (ρ_{t+1}, ρ_{t+2}) while
    // their sum stays positive
    let mut rho_hat = vec![0.0; n + 1];
    rho_hat[0] = 1.0;
    rho_hat[1] = rho(1);
    let (mut even, mut odd) = (1.0, rho_hat[1]);
    let mut t = 1;
    while t < n - 3 && even + odd > 0.0 {
        even = rho(t + 1);
        odd = rho(t + 2);
        if even + odd >= 0.0 {
            rho_hat[t + 1] = even;
            rho_hat[t + 2] = odd;
        }
        t += 2;
    }
    // the last positive pair ends at max_t; a positive even term after it
    // still counts (half of it, through the sum below)
    if t < 3 {
        return f64::NAN;
    }
    let max_t = t - 2;
    if even > 0.0 {
        rho_hat[max_t + 1] = even;
    }
    // initial monotone sequence: pair sums may not increase
    let mut s = 1;
    while s + 2 <= max_t {
        let prev = rho_hat[s - 1] + rho_hat[s];
        if rho_hat[s + 1] + rho_hat[s + 2] > prev {
            rho_hat[s + 1] = prev / 2.0;
            rho_hat[s + 2] = prev / 2.0;
        }
        s += 2;
    }
    let total = (m * n) as f64;
    let tau = -1.0 + 2.0 * rho_hat[..=max_t].iter().sum::<f64>() + rho_hat[max_t + 1];
    let tau = tau.max(1.0 / total.log10());
    total / tau
}

/// Bulk ESS: ESS of the rank-normalised split chains.
pub fn ess_bulk(chains: &[Vec<f64>]) -> f64 {
    ess(&rank_normalize(&split(chains)))
}

/// Tail ESS: the smaller ESS of the indicators of the 5 % and 95 % quantiles.
pub fn ess_tail(chains: &[Vec<f64>]) -> f64 {
    let s = split(chains);
    let all = pool(&s);
    [0.05, 0.95]
        .iter()
        .map(|&p| {
            let q = quantile(&all, p);
            let ind: Vec<Vec<f64>> = s
                .iter()
                .map(|c| c.iter().map(|x| if *x <= q { 1.0 } else { 0.0 }).collect())
                .collect();
            ess(&ind)
        })
        .fold(f64::INFINITY, nan_min)
}

/// The smaller of two ESS values, NaN (chains too short to tell) if either
/// is: `f64::min` would drop the NaN and report the other.
fn nan_min(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.min(b)
    }
}

fn pool(chains: &[Vec<f64>]) -> Vec<f64> {
    chains.iter().flatten().copied().collect()
}

/// Quantile `p` of `x` by linear interpolation between order statistics
/// (Hyndman & Fan type 7, as numpy's default).
pub fn quantile(x: &[f64], p: f64) -> f64 {
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    quantile_sorted(&v, p)
}

pub fn quantile_sorted(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let h = (v.len() - 1) as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(v.len() - 1);
    v[lo] + (h - lo as f64) * (v[hi] - v[lo])
}

/// Summary and diagnostics of one quantity.
#[derive(Clone, Debug, PartialEq)]
pub struct ParameterDiagnostics {
    pub mean: f64,
    pub sd: f64,
    pub q05: f64,
    pub q50: f64,
    pub q95: f64,
    pub ess_bulk: f64,
    pub ess_tail: f64,
    pub r_hat: f64,
    pub tau_int: f64,
    /// Monte Carlo standard error of the mean: sd / √ESS of the raw draws.
    pub mcse_mean: f64,
}

/// The draws of each group of consecutive chains (an ensemble) as one
/// chain, step by step: `[group][step * walkers + walker]`.
fn group_chains(chains: &[Vec<f64>], groups: usize) -> Vec<Vec<f64>> {
    let per = chains.len() / groups.max(1);
    let n = chains.iter().map(Vec::len).min().unwrap_or(0);
    (0..groups)
        .map(|g| {
            let members = &chains[g * per..(g + 1) * per];
            (0..n).flat_map(|s| members.iter().map(move |c| c[s])).collect()
        })
        .collect()
}

/// Of `available` draws per chain, how many the diagnostics use: the last
/// ones, an even number, so halves split cleanly and every arrangement
/// ranks the same draws.
pub fn analysed_draws(available: usize) -> usize {
    available / 2 * 2
}

impl ParameterDiagnostics {
    /// The smaller of the bulk and tail ESS (NaN if either is).
    pub fn ess(&self) -> f64 {
        nan_min(self.ess_bulk, self.ess_tail)
    }

    /// Diagnostics of `[chain][draw]` traces whose chains form `ensembles`
    /// equal groups of consecutive walkers.
    ///
    /// R̂ compares the ensembles: each ensemble's draws, step by step, form
    /// one chain (split in halves in time). Walkers of one ensemble are not
    /// independent, and a walker alone is too short for R̂ to settle (its
    /// own ESS is ~N/τ), while ensembles are independent by construction.
    /// ESS and τ use every walker's chain.
    pub fn of(chains: &[Vec<f64>], ensembles: usize) -> Self {
        let n = analysed_draws(chains.iter().map(Vec::len).min().unwrap_or(0));
        let chains: Vec<Vec<f64>> = chains.iter().map(|c| c[c.len() - n..].to_vec()).collect();
        let chains = &chains[..];
        // normal scores of all draws and of the folded draws, made once
        let z = rank_normalize(chains);
        let z_folded = rank_normalize(&folded(chains));
        let all = pool(chains);
        let mut sorted = all.clone();
        sorted.sort_by(f64::total_cmp);
        let sd = variance(&all).sqrt();
        ParameterDiagnostics {
            mean: mean(&all),
            sd,
            q05: quantile_sorted(&sorted, 0.05),
            q50: quantile_sorted(&sorted, 0.5),
            q95: quantile_sorted(&sorted, 0.95),
            ess_bulk: ess(&split(&z)),
            ess_tail: ess_tail(chains),
            r_hat: rhat_of_normalized(
                &group_chains(&z, ensembles),
                &group_chains(&z_folded, ensembles),
            ),
            tau_int: integrated_time(chains),
            mcse_mean: sd / ess(&split(chains)).sqrt(),
        }
    }
}

/// The walkers whose acceptance over `steps` steps is improbably low for a
/// walker accepting at the `median` rate (binomial tail, Bonferroni over
/// the walkers).
fn stuck_walkers(acceptance: &[f64], median: f64, steps: usize) -> Vec<usize> {
    use statrs::distribution::{Binomial, DiscreteCDF};
    let Ok(rate) = Binomial::new(median.clamp(0.0, 1.0), steps as u64) else { return vec![] };
    let limit = STUCK_P / acceptance.len().max(1) as f64;
    acceptance
        .iter()
        .enumerate()
        .filter(|(_, a)| rate.cdf((**a * steps as f64).round() as u64) < limit)
        .map(|(c, _)| c)
        .collect()
}

fn max_rhat(coordinates: &[ParameterDiagnostics]) -> f64 {
    largest_rhat(coordinates.iter().map(|c| c.r_hat))
}

/// The largest of some R̂s; NaN where any is NaN (a coordinate whose draws
/// do not spread: stuck walkers), as the stopping rule counts it — not the
/// largest of the others, which would hide it. 0 for none.
pub fn largest_rhat(rhats: impl IntoIterator<Item = f64>) -> f64 {
    rhats.into_iter().fold(0.0, |m, r| if m.is_nan() || r.is_nan() { f64::NAN } else { m.max(r) })
}

/// Diagnostics of a whole run.
#[derive(Clone, Debug)]
pub struct Diagnostics {
    /// Steps (after the initial state) in the chains.
    pub steps: usize,
    /// Draws discarded at the start of every chain.
    pub burn_in: usize,
    /// One per coordinate of the sampled space.
    pub coordinates: Vec<ParameterDiagnostics>,
    /// Largest τ over coordinates.
    pub tau_max: f64,
    /// Acceptance fraction per chain after burn-in.
    pub acceptance: Vec<f64>,
    /// Chains whose acceptance is below a fifth of the median (or zero).
    pub stuck: Vec<usize>,
    /// The coordinate whose draws still drift, if any: after the burn-in,
    /// or after the first third of the chain where the burn-in is longer
    /// ([`super::drift`]).
    pub drift: Option<Drift>,
    pub warnings: Vec<String>,
}

impl Diagnostics {
    /// Diagnostics after discarding `burn_in` draws (e.g. by
    /// [`Self::burn_in_rule`]).
    pub fn compute(chains: &Chains, burn_in: usize) -> Diagnostics {
        let coordinates: Vec<ParameterDiagnostics> = (0..chains.dim)
            .into_par_iter()
            .map(|i| ParameterDiagnostics::of(&chains.traces(i, burn_in), chains.ensembles))
            .collect();
        Diagnostics::assemble(chains, burn_in, coordinates)
    }

    /// The default burn-in: 3 τ_max with τ estimated on the second half of
    /// the chains, at most half the chain. With moves that adapt to the
    /// history (`adaptive`), also every step before the window that the
    /// last fit saw: the stages before it proposed from fits to a chain
    /// that may not have converged yet, which τ, measured at equilibrium,
    /// does not show. After a stranded ensemble was drawn afresh
    /// ([`super::stranded`]), the rule counts from that step.
    pub fn burn_in_rule(chains: &Chains, adaptive: bool) -> usize {
        let total = chains.steps();
        let tau = (0..chains.dim)
            .map(|i| integrated_time(&chains.traces(i, total / 2)))
            .fold(1.0, f64::max);
        let taus = (BURN_IN_TAUS * tau).ceil() as usize;
        // after an ensemble was drawn afresh, the rule counts from there
        let redrawn = super::stranded::last_step(chains);
        let rule = (taus.min(total / 2)).max(redrawn + taus.min(total.saturating_sub(redrawn) / 2));
        let rule = if adaptive {
            rule.max(super::moves::mixture::last_fit_step(total.saturating_sub(1)) / 2)
        } else {
            rule
        };
        past_drift(chains, rule)
    }

    /// Builds the run's diagnostics from per-coordinate ones (a caller may
    /// compute those on transformed draws).
    pub fn assemble(
        chains: &Chains,
        burn_in: usize,
        coordinates: Vec<ParameterDiagnostics>,
    ) -> Diagnostics {
        let total = chains.steps();
        let kept = total.saturating_sub(burn_in);
        let tau_max = coordinates.iter().map(|c| c.tau_int).fold(0.0, f64::max);
        let acceptance = chains.acceptance(burn_in.max(1));
        let mut sorted = acceptance.clone();
        sorted.sort_by(f64::total_cmp);
        let median = quantile_sorted(&sorted, 0.5);
        let stuck = stuck_walkers(&acceptance, median, total.saturating_sub(burn_in.max(1)));
        // the draws after the burn-in, or after the first third of the
        // chain where the burn-in is longer: a transient longer than a
        // third of the chain is not yet cut away reliably (the test's
        // windows are short), so the run waits for it
        let drift = drift(chains, burn_in.min(total / 3));
        let mut warnings = Vec::new();
        if (kept as f64) < MIN_TAU_MULTIPLE * tau_max {
            warnings.push(format!(
                "chains are {kept} steps after burn-in, shorter than {MIN_TAU_MULTIPLE} τ = {:.0}: run longer",
                MIN_TAU_MULTIPLE * tau_max
            ));
        }
        let worst_rhat = max_rhat(&coordinates);
        if !(worst_rhat < RHAT_THRESHOLD) {
            warnings
                .push(format!("largest R̂ is {worst_rhat:.3} ≥ {RHAT_THRESHOLD}: chains disagree"));
        }
        if let Some(d) = &drift {
            warnings.push(format!(
                "the draws still drift: a coordinate's {} moved by {:.1} standard errors from the first quarter of the draws after step {} to their last half (target within ±{DRIFT_Z}): the walkers have not forgotten their start, all ensembles alike, which R̂ does not see; run longer",
                match d.moment {
                    Moment::Mean => "mean",
                    Moment::Spread => "spread",
                },
                d.z,
                d.from
            ));
        }
        if median < LOW_ACCEPTANCE {
            warnings.push(format!(
                "proposals were accepted at a median rate of {median:.3} per walker and step (below {LOW_ACCEPTANCE}): the posterior is far from the shapes the moves propose (curved, skewed or against a bound), and R̂ and ESS can pass before the walkers have visited a region they rarely reach; check the parameters that matter with a run three times as long, `--steps {}` (docs/calibration.md, \"Convergence\")",
                3 * total.saturating_sub(1).max(1)
            ));
        }
        if !stuck.is_empty() {
            warnings.push(format!(
                "{} walker(s) stuck (far fewer accepted proposals than the median rate {median:.2} would give): chains {:?}",
                stuck.len(),
                stuck
            ));
        }
        Diagnostics {
            steps: total.saturating_sub(1),
            burn_in,
            coordinates,
            tau_max,
            acceptance,
            stuck,
            drift,
            warnings,
        }
    }

    /// The largest R̂ over coordinates.
    pub fn max_rhat(&self) -> f64 {
        max_rhat(&self.coordinates)
    }

    /// The smallest bulk or tail ESS over coordinates.
    pub fn min_ess(&self) -> f64 {
        self.coordinates.iter().map(ParameterDiagnostics::ess).fold(f64::INFINITY, nan_min)
    }

    /// At least [`MIN_TAU_MULTIPLE`] τ_max after burn-in.
    pub fn long_enough(&self) -> bool {
        self.long_enough_for(MIN_TAU_MULTIPLE)
    }

    fn long_enough_for(&self, tau_multiple: f64) -> bool {
        (self.steps + 1).saturating_sub(self.burn_in) as f64 >= tau_multiple * self.tau_max
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;
    use rand_distr::StandardNormal;

    fn ar1(rho: f64, n: usize, stream: u64) -> Vec<f64> {
        let mut rng = crate::rng::stream(99, &[stream]);
        let s = (1.0 - rho * rho).sqrt();
        let mut x = rng.sample::<f64, _>(StandardNormal);
        (0..n)
            .map(|_| {
                x = rho * x + s * rng.sample::<f64, _>(StandardNormal);
                x
            })
            .collect()
    }

    #[test]
    fn autocovariance_matches_direct_sum() {
        let x = ar1(0.5, 257, 1);
        let m = mean(&x);
        let acov = autocovariance(&x);
        for t in [0, 1, 5, 100, 256] {
            let direct: f64 =
                (0..x.len() - t).map(|i| (x[i] - m) * (x[i + t] - m)).sum::<f64>() / x.len() as f64;
            assert!((acov[t] - direct).abs() < 1e-12, "{t}");
        }
    }

    #[test]
    fn ar1_integrated_time_matches_theory() {
        // τ = (1 + ρ)/(1 − ρ) = 19 for ρ = 0.9. With 32 chains of 5000 draws
        // the estimator's relative sd is about √(2(2M+1)/(32·5000)) ≈ 3.5 %
        // for window M ≈ 5τ; 12 % is over 3 sd.
        let chains: Vec<Vec<f64>> = (0..32).map(|c| ar1(0.9, 5000, c)).collect();
        let tau = integrated_time(&chains);
        assert!((tau - 19.0).abs() < 0.12 * 19.0, "τ = {tau}");
        // ESS agrees: N M / τ within the same tolerance
        let e = ess(&chains);
        let expected = 32.0 * 5000.0 / 19.0;
        assert!((e - expected).abs() < 0.12 * expected, "ESS {e} vs {expected}");
    }

    #[test]
    fn ess_of_independent_draws_is_about_n() {
        // i.i.d.: ρ_t ≈ 0, so ESS ≈ N; Geyer's truncation after a few lags
        // leaves a relative sd of a few percent at N = 4000
        let chains: Vec<Vec<f64>> = (0..4).map(|c| ar1(0.0, 1000, 10 + c)).collect();
        for (name, e) in
            [("bulk", ess_bulk(&chains)), ("tail", ess_tail(&chains)), ("raw", ess(&chains))]
        {
            assert!((e - 4000.0).abs() < 0.15 * 4000.0, "{name}: {e}");
        }
    }

    #[test]
    fn too_short_chains_have_no_ess() {
        // split halves of 5 draws are shorter than the 4 lags ESS needs:
        // unknown, not infinite (which would pass any ESS target)
        let chains: Vec<Vec<f64>> = (0..4).map(|c| ar1(0.0, 5, 30 + c)).collect();
        assert!(ess_bulk(&chains).is_nan() && ess_tail(&chains).is_nan());
    }

    #[test]
    fn rhat_separates_agreeing_and_shifted_chains() {
        let same: Vec<Vec<f64>> = (0..4).map(|c| ar1(0.0, 1000, 20 + c)).collect();
        let r = split_rhat(&same);
        assert!(r < 1.01, "same distribution: {r}");
        // one chain shifted by half a standard deviation
        let mut shifted = same.clone();
        for x in shifted[0].iter_mut() {
            *x += 0.5;
        }
        let r = split_rhat(&shifted);
        assert!(r > 1.02, "shifted: {r}");
        // a chain with a different scale shows in the folded (tail) R̂
        let mut wide = same;
        for x in wide[1].iter_mut() {
            *x *= 2.0;
        }
        assert!(split_rhat(&wide) > 1.02);
    }

    #[test]
    fn quantiles_interpolate_like_numpy() {
        let x = [3.0, 1.0, 2.0, 4.0];
        assert_eq!(quantile(&x, 0.5), 2.5);
        assert_eq!(quantile(&x, 0.0), 1.0);
        assert!((quantile(&x, 0.05) - 1.15).abs() < 1e-12);
    }
}
