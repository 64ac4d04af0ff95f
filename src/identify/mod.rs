//! The paper's deterministic identification (§3), with the slips of its
//! printed equations corrected (see the design notes in the README):
//!
//! 1. per run: τ, γ (eq. 1), G from the initial elastic slope ([`elastic`]),
//!    γᴵ and γ̇ᴵ (eqs. 1–2);
//! 2. τ02 at γᴵ = 0.2 % with γ̇ᴵ there, and n, R0 from eq. 6 over the runs
//!    of one current ([`yield_stress`]);
//! 3. eq. 7 fitted to τ(γᴵ), ψ(τ) from eqs. 8–9, its end slopes → m2, m1,
//!    its intercepts → R1, D1 ([`hardening`]);
//! 4. per-run values and one combined estimate per current, clamped into
//!    the physical range with a warning where needed;
//! 5. an Euler solution with the combined parameters against every record.
//!
//! Records that do not start with a full-stroke loading from rest (a
//! servo-hydraulic test whose amplitude ramps up, say) take the route of
//! [`steady`]: G and the flow curve from steady cycles.
//!
//! The result is a starting point for the sampler, not an answer.

pub mod elastic;
pub mod hardening;
pub mod steady;
pub mod yield_stress;

use serde::{Deserialize, Serialize};

use crate::data::{Campaign, Run};
use crate::model::{Integrator, Params, PARAM_NAMES};
use hardening::{Asymptote, CurveFit, Eq7};
use yield_stress::YieldFit;

/// Choices of the identification; the defaults are the documented rules.
/// `mrbp identify` sets the first two from its options, a settings file
/// (`[identify]`) any.
#[derive(clap::Args, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IdentifySettings {
    /// Loading branch of each record to identify from (0: the first, from rest)
    #[arg(long, default_value_t = IdentifySettings::default().branch)]
    pub branch: usize,
    /// Half-width (ms) of the smoothing of τ, γ and their derivatives
    #[arg(long, default_value_t = IdentifySettings::default().smooth_ms)]
    pub smooth_ms: f64,
    /// G is fitted while τ has covered less than this share of its rise.
    #[arg(skip = IdentifySettings::default().elastic_share)]
    pub elastic_share: f64,
    /// The offset inelastic strain of the yield point (0.2 %).
    #[arg(skip = IdentifySettings::default().offset_strain)]
    pub offset_strain: f64,
    /// Share of the τ span of ψ(τ) that counts as each end.
    #[arg(skip = IdentifySettings::default().end_share)]
    pub end_share: f64,
    /// Points of τ(γᴵ) used for the eq. 7 fit, log-spaced in γᴵ.
    #[arg(skip = IdentifySettings::default().curve_points)]
    pub curve_points: usize,
    /// Half-width (ms) of the local cubic that smooths the strain driving
    /// the Euler check of the combined estimate (the calibration's default).
    #[arg(skip = IdentifySettings::default().drive_smooth_ms)]
    pub drive_smooth_ms: f64,
}

impl IdentifySettings {
    /// Refuses a smoothing width that is not positive.
    pub fn check(&self) -> crate::Result<()> {
        if !(self.smooth_ms > 0.0) {
            return Err(crate::Error::Usage(format!(
                "--smooth-ms must be positive, got {}",
                self.smooth_ms
            )));
        }
        Ok(())
    }
}

impl Default for IdentifySettings {
    fn default() -> Self {
        IdentifySettings {
            branch: 0,
            smooth_ms: 0.5,
            elastic_share: 0.4,
            offset_strain: 0.002,
            end_share: 0.15,
            curve_points: 200,
            drive_smooth_ms: 2.0,
        }
    }
}

/// What the identification found for one run.
#[derive(Clone, Debug)]
pub struct RunIdentification {
    pub run: String,
    pub current_a: f64,
    pub branch: std::ops::Range<usize>,
    pub g: f64,
    pub elastic_points: usize,
    /// τ02 (Pa) and γ̇ᴵ there (1/s); `None` if γᴵ never reached the offset.
    pub yield_point: Option<(f64, f64)>,
    /// τ(γᴵ) samples used for eq. 7 (γᴵ from the branch start, τ).
    pub curve_data: (Vec<f64>, Vec<f64>),
    pub curve: Option<CurveFit>,
    /// ψ(τ) along the fitted curve.
    pub psi: (Vec<f64>, Vec<f64>),
    /// (small-strain end → m2, large-strain end → m1)
    pub ends: Option<(Asymptote, Asymptote)>,
    /// m1, m2, R1, D1 of this run, before clamping (NaN where not found).
    pub m1: f64,
    pub m2: f64,
    pub r1: f64,
    pub d1: f64,
    /// The steady-cycle route's result, for a record not from rest.
    pub steady: Option<steady::SteadyFit>,
    pub warnings: Vec<String>,
}

impl RunIdentification {
    /// A run's identification with G found on `branch` and nothing past
    /// yield yet: the route (from rest, or steady cycles) fills in the rest.
    fn with_g(
        run: &Run,
        branch: std::ops::Range<usize>,
        g: f64,
        elastic_points: usize,
        warnings: Vec<String>,
    ) -> Self {
        RunIdentification {
            run: run.id().to_string(),
            current_a: run.spec.current_a,
            branch,
            g,
            elastic_points,
            yield_point: None,
            curve_data: (vec![], vec![]),
            curve: None,
            psi: (vec![], vec![]),
            ends: None,
            m1: f64::NAN,
            m2: f64::NAN,
            r1: f64::NAN,
            d1: f64::NAN,
            steady: None,
            warnings,
        }
    }
}

/// The identification of one current level.
#[derive(Clone, Debug)]
pub struct CurrentIdentification {
    pub current_a: f64,
    pub runs: Vec<RunIdentification>,
    pub yield_fit: YieldFit,
    /// The combined estimate as computed, before clamping.
    pub raw: [f64; 7],
    /// The combined estimate inside the physical range: the sampler's start.
    pub params: Params,
    /// RMS of τ_Euler − τ_data per run over the whole record (Pa), with the
    /// combined parameters; NaN where the integration failed.
    pub euler_rms: Vec<f64>,
    /// τ of the Euler solution per run (empty where it failed).
    pub euler_tau: Vec<Vec<f64>>,
    /// How the estimate was reached where the records do not allow the
    /// paper's route: steady cycles only, no loading from rest (one line).
    pub route: Option<String>,
    /// What went wrong or was forced on the way.
    pub warnings: Vec<String>,
}

fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// D1's share of the saturated hardening R1 + D1 where the records do not
/// show it (steady cycles only): the middle of the plausible ranges.
const D1_SHARE: f64 = 0.2;

/// Steps 1–3 for one run, except R1 and D1, which need R0 of the current;
/// or the steady-cycle route for a record not from rest.
fn identify_run(run: &Run, s: &IdentifySettings) -> RunIdentification {
    if s.branch == 0 && !steady::starts_from_rest(run) {
        return identify_steady(run, s);
    }
    let mut warnings = Vec::new();
    let branch = run.branches.get(s.branch).cloned().unwrap_or_else(|| {
        warnings.push(format!("run has {} branches; using the first", run.branches.len()));
        run.branches[0].clone()
    });
    let sh = &run.shear;
    let dt = (sh.time[sh.len() - 1] - sh.time[0]) / (sh.len() - 1) as f64;
    let half_window = ((s.smooth_ms * 1e-3 / dt).round() as usize).max(1);
    // smoothing of the whole record, so that branch ends see both sides
    let provisional = sh.inelastic(1.0, half_window);
    let b = branch.clone();
    let (g, elastic_points) = elastic::elastic_modulus(
        &sh.gamma[b.clone()],
        &sh.tau[b.clone()],
        &provisional.tau_smooth[b.clone()],
        s.elastic_share,
    );
    let mut out = RunIdentification::with_g(run, branch.clone(), g, elastic_points, warnings);
    if elastic_points < 5 {
        out.warnings.push(format!("only {elastic_points} samples in the elastic part: G is rough"));
    }
    if !(g > 0.0) {
        out.warnings.push(format!("elastic slope {g:.3e} Pa is not positive"));
        return out;
    }
    let ie = sh.inelastic(g, half_window);
    // the loading direction of the branch, and γᴵ, τ, γ̇ᴵ in it from its start
    let sign = if ie.tau_smooth[b.end - 1] >= ie.tau_smooth[b.start] { 1.0 } else { -1.0 };
    // γᴵ at the start of the branch: its mean over the elastic samples, where
    // it is constant but for noise (a single sample would shift the offset
    // by the noise, which is as large as the 0.2 % offset itself)
    let x0 =
        ie.strain[b.start..b.start + elastic_points].iter().sum::<f64>() / elastic_points as f64;
    let strain: Vec<f64> = ie.strain_smooth[b.clone()].iter().map(|v| sign * (v - x0)).collect();
    let tau: Vec<f64> = ie.tau_smooth[b.clone()].iter().map(|v| sign * v).collect();
    let rate: Vec<f64> = ie.rate[b.clone()].iter().map(|v| sign * v).collect();
    let Some((tau02, rate02, k02)) =
        yield_stress::offset_yield(&strain, &tau, &rate, s.offset_strain)
    else {
        out.warnings.push(format!("inelastic strain never reaches {} %", s.offset_strain * 100.0));
        return out;
    };
    if !(rate02 > 0.0) {
        out.warnings.push(format!("inelastic rate at yield is {rate02:.3e} 1/s, not positive"));
        return out;
    }
    out.yield_point = Some((tau02, rate02));
    fit_hardening(&mut out, &strain, &tau, k02, s);
    out
}

/// Step 3 for one run: eq. 7 on τ(γᴵ) from the yield sample `k02` up to the
/// peak of τ (beyond it the falling crank speed, not hardening, shapes the
/// curve), ψ(τ) along it, and m1, m2 from its end slopes.
fn fit_hardening(
    out: &mut RunIdentification,
    strain: &[f64],
    tau: &[f64],
    k02: usize,
    s: &IdentifySettings,
) {
    let peak = (k02..tau.len()).max_by(|&i, &j| tau[i].total_cmp(&tau[j])).unwrap_or(k02);
    let (xs, ys) =
        resample_log(&strain[k02..=peak], &tau[k02..=peak], s.offset_strain, s.curve_points);
    if xs.len() < 8 {
        out.warnings.push(format!("only {} points past yield for eq. 7", xs.len()));
        out.curve_data = (xs, ys);
        return;
    }
    let fit = hardening::fit_eq7(&xs, &ys);
    if !fit.converged {
        out.warnings.push("eq. 7 fit did not converge".into());
    }
    let f: Eq7 = fit.eq7;
    let psi_tau: Vec<f64> = xs.iter().map(|x| f.value(*x)).collect();
    let psi: Vec<f64> = xs.iter().map(|x| f.psi(*x)).collect();
    out.ends = hardening::asymptotes(&psi_tau, &psi, s.end_share);
    match out.ends {
        Some((small, large)) => {
            out.m2 = small.m;
            out.m1 = large.m;
            if !(small.m > 0.0) {
                out.warnings.push(format!("small-strain slope gives m2 = {:.3e} ≤ 0", small.m));
            }
            if !(large.m > 0.0) {
                out.warnings.push(format!("large-strain slope gives m1 = {:.3e} ≤ 0", large.m));
            }
        }
        None => out.warnings.push("ψ(τ) has no usable ends".into()),
    }
    out.curve = Some(fit);
    out.curve_data = (xs, ys);
    out.psi = (psi_tau, psi);
}

/// The steady-cycle route ([`steady`]) for one record.
fn identify_steady(run: &Run, s: &IdentifySettings) -> RunIdentification {
    let sh = &run.shear;
    let dt = (sh.time[sh.len() - 1] - sh.time[0]) / (sh.len() - 1) as f64;
    let half_window = ((s.smooth_ms * 1e-3 / dt).round() as usize).max(2);
    let (tau, _) = crate::data::local_polynomial(&sh.time, &sh.tau, half_window, 3);
    let (gamma, rate) = crate::data::local_polynomial(&sh.time, &sh.gamma, half_window, 3);
    let fit = steady::identify(run, &tau, &gamma, &rate);
    let warnings = match &fit {
        Ok(_) => vec![],
        Err(why) => vec![format!("steady cycles: {why}")],
    };
    let branch = run.branches[steady::first_full_stroke(run)].clone();
    let g = fit.as_ref().map_or(f64::NAN, |f| f.g);
    let elastic_points = fit.as_ref().map_or(0, |f| f.reversals);
    RunIdentification {
        steady: fit.ok(),
        ..RunIdentification::with_g(run, branch, g, elastic_points, warnings)
    }
}

/// `n` points of the curve y(x) at x log-spaced from `from` to the largest x,
/// by linear interpolation on the running maximum of x (so a noisy,
/// non-monotone x cannot make the interpolation ambiguous).
fn resample_log(x: &[f64], y: &[f64], from: f64, n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut xm = Vec::with_capacity(x.len());
    let mut run = f64::NEG_INFINITY;
    for v in x {
        run = run.max(*v);
        xm.push(run);
    }
    let top = run;
    if !(top > from) || n < 2 {
        return (vec![], vec![]);
    }
    let (la, lb) = (from.ln(), top.ln());
    let mut xs = Vec::with_capacity(n);
    let mut ys = Vec::with_capacity(n);
    for i in 0..n {
        let target = (la + (lb - la) * i as f64 / (n - 1) as f64).exp().min(top);
        let k = xm.partition_point(|v| *v < target);
        let y = if k == 0 {
            y[0]
        } else if k >= xm.len() {
            y[y.len() - 1]
        } else if xm[k] == xm[k - 1] {
            y[k]
        } else {
            let w = (target - xm[k - 1]) / (xm[k] - xm[k - 1]);
            y[k - 1] + w * (y[k] - y[k - 1])
        };
        xs.push(target);
        ys.push(y);
    }
    (xs, ys)
}

/// The whole identification of the runs of one current level.
pub fn identify_current(
    campaign: &Campaign,
    current_a: f64,
    s: &IdentifySettings,
) -> CurrentIdentification {
    let group = campaign.at_current(current_a);
    let mut runs: Vec<RunIdentification> = group.runs.iter().map(|r| identify_run(r, s)).collect();
    let mut warnings = Vec::new();

    let points: Vec<(f64, f64)> =
        runs.iter().filter_map(|r| r.yield_point.map(|(t, g)| (g, t))).collect();
    let steady: Vec<&steady::SteadyFit> = runs.iter().filter_map(|r| r.steady.as_ref()).collect();
    let steady_z = median(&steady.iter().map(|f| f.z).collect::<Vec<_>>());
    let steady_n = median(&steady.iter().map(|f| f.n).collect::<Vec<_>>());
    let mut yield_fit = yield_stress::fit_eq6(&points);
    let steady_only = points.is_empty() && !steady.is_empty();
    if steady_only {
        // no loading from rest: the initial yield of R0 cannot be seen, and
        // R0 starts at the saturated value of R (no isotropic hardening)
        yield_fit = yield_stress::YieldFit {
            r0: (1.0 - D1_SHARE) * steady_z,
            n: steady_n,
            converged: true,
            rms_log: f64::NAN,
            note: None,
        };
    } else if yield_fit.n == 1.0 && yield_fit.note.is_some() && steady_n.is_finite() {
        yield_fit.note = Some(format!(
            "{}; n = {steady_n:.3} from the flow curve of steady cycles instead",
            yield_fit.note.as_deref().unwrap_or("")
        ));
        yield_fit.n = steady_n;
    }
    if let Some(note) = &yield_fit.note {
        warnings.push(note.clone());
    }
    for r in runs.iter_mut() {
        if let (Some((tau02, _)), Some((small, large))) = (r.yield_point, r.ends) {
            let kappa = tau02 / yield_fit.r0;
            let (r1, d1) = hardening::solve_r1_d1(
                large.intercept, small.intercept, large.m, small.m, yield_fit.r0, kappa,
            );
            r.r1 = r1;
            r.d1 = d1;
        }
    }
    // per-run values that are not positive are not estimates: left out
    let positive = |f: &dyn Fn(&RunIdentification) -> f64| {
        runs.iter().map(f).filter(|v| *v > 0.0).collect::<Vec<f64>>()
    };
    let g = positive(&|r| r.g);
    let mut raw = [
        g.iter().sum::<f64>() / g.len().max(1) as f64,
        yield_fit.r0,
        median(&positive(&|r| r.r1)),
        median(&positive(&|r| r.d1)),
        median(&positive(&|r| r.m1)),
        median(&positive(&|r| r.m2)),
        yield_fit.n,
    ];
    let split = !(raw[2].is_finite() && raw[3].is_finite()) && steady_z.is_finite();
    if split {
        raw[2] = (1.0 - D1_SHARE) * steady_z;
        raw[3] = D1_SHARE * steady_z;
        if !steady_only {
            warnings.push(format!("R1 + D1 = {steady_z:.3e} Pa from the flow curve of steady cycles, D1 its {:.0} % (the split shows only in a loading from rest)", 100.0 * D1_SHARE));
        }
    }
    let mut centred = Vec::new();
    for (i, name) in PARAM_NAMES.iter().enumerate() {
        if !(raw[i] > 0.0) {
            raw[i] = Params::plausible_centre(i);
            match steady_only && (*name == "m1" || *name == "m2") {
                true => centred.push(format!("{name} = {:.1e}", raw[i])),
                false => warnings.push(format!("no run gives {name}: the middle of its plausible range, {:.3e}, starts the calibration", raw[i])),
            }
        }
    }
    // steady cycles only: the route in one line, its forced choices named
    let route = steady_only.then(|| {
        let mut line = format!(
            "steady cycles only (no record starts from rest): n = {steady_n:.3} and R + D = {steady_z:.3e} Pa from their flow curve; R0 = R1 = {:.0} % of R + D, D1 {:.0} %",
            100.0 * (1.0 - D1_SHARE),
            100.0 * D1_SHARE
        );
        if !centred.is_empty() {
            let which = if centred.len() == 1 { "the middle of its plausible range" } else { "the middles of their plausible ranges" };
            line.push_str(&format!("; {}, {which}", centred.join(" and ")));
        }
        line
    });
    let (params, moved) = Params::from_array(raw).clamped();
    for name in moved {
        let i = PARAM_NAMES.iter().position(|n| *n == name).unwrap_or(0);
        warnings.push(format!(
            "{name} = {:.3e} is outside the physical range: clamped to {:.3e}",
            raw[i],
            params.to_array()[i]
        ));
    }
    let (euler_rms, euler_tau) = euler_check(&group, &params, s, &mut warnings);
    CurrentIdentification {
        current_a,
        runs,
        yield_fit,
        raw,
        params,
        euler_rms,
        euler_tau,
        route,
        warnings,
    }
}

/// The paper's check of the combined estimate: the explicit Euler solution
/// along every run of `group`, driven by the strain the calibration uses
/// (smooth, not quantised), and its RMS misfit per run.
fn euler_check(
    group: &Campaign,
    params: &Params,
    s: &IdentifySettings,
    warnings: &mut Vec<String>,
) -> (Vec<f64>, Vec<Vec<f64>>) {
    let integ = Integrator { max_substeps: 100_000, ..Integrator::default() };
    group
        .runs
        .iter()
        .map(|run| {
            let sh = &run.shear;
            let mut tau = vec![0.0; sh.len()];
            let init = crate::model::State { tau: sh.initial_tau, w: 0.0 };
            let gamma = crate::data::smoothed_strain(&sh.time, &sh.gamma, s.drive_smooth_ms);
            match integ.run_with(params, &sh.time, &gamma, init, |k, st| tau[k] = st.tau) {
                Ok(_) => {
                    let ss: f64 = tau.iter().zip(&sh.tau).map(|(m, o)| (m - o).powi(2)).sum();
                    ((ss / sh.len() as f64).sqrt(), tau)
                }
                Err(e) => {
                    warnings.push(format!("Euler solution of run {} failed: {e}", run.id()));
                    (f64::NAN, vec![])
                }
            }
        })
        .unzip()
}

/// One identification per current level of the campaign, ascending current.
pub fn identify_campaign(campaign: &Campaign, s: &IdentifySettings) -> Vec<CurrentIdentification> {
    campaign.currents().into_iter().map(|c| identify_current(campaign, c, s)).collect()
}
