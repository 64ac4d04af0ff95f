//! Where each quantity sits in a point of the posterior, and the map
//! between the sampler's unconstrained coordinates and SI units.
//!
//! A point is θ (the parameter model's coordinates), then the terms of
//! [`ModelTerms`] that are on (the gas-spring stiffness, a force offset per
//! run), then the noise model's parameters, one block per parameter with a
//! coordinate per run (every σ, then every ρ, …). The sampler walks θ in its
//! [`Coordinates`] (ln θ, with the stresses recombined; another law's
//! parameters as ln(θ − floor), [`Layout::floors`]), the terms as they are and each
//! noise parameter in its [`Transform`]; outputs use θ, the terms and the
//! noise in SI units under the names `G` … (or a law's),
//! `gas_spring_n_per_m`, `force_offset_n_<run>`, `sigma_<run>`, `rho_<run>`, ….

use std::ops::Range;

use serde::{Deserialize, Serialize};

use super::parameters::ParameterModel;
use super::terms::ModelTerms;
use crate::noise::{NoiseModel, NoiseValues, Parameter, Transform, MAX_PARAMETERS};

/// The coordinates the sampler walks θ in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Coordinates {
    /// ln θ (another law's parameters: ln(θ − floor), see [`Layout`]).
    Log,
    /// ln θ, but R1 and D1 as ln(R1 + D1), the saturated stress the records
    /// pin down, and logit of D1's share of it, ln(D1/R1), which they may
    /// not: the ridge R1 + D1 ≈ const, curved in ln R1 and ln D1, becomes
    /// straight. The map from (ln R1, ln D1) has Jacobian 1, so densities of
    /// ln θ carry over unchanged.
    SaturationShare,
    /// ln θ, but the three stresses as the records fix them (per-current
    /// parameters, a law's B-P element, each anchor of the current curves;
    /// the current law walks [`Self::SaturationShare`]):
    /// ln(R0 + D1), the flow stress once D has saturated, and ln(D1/R0),
    /// its share (Jacobian 1, as above); and instead of ln R1 the log of
    /// the drag stress R + D after the records' plastic work W*
    /// ([`Hardening`]). Where that work hardens little (m1 W* ≪ 1) the
    /// records fix m1 (R1 − R0), a ridge curved in ln R1 and ln m1 and
    /// straight in these; where it saturates, R1 + D1: the same
    /// coordinate either way.
    Hardening,
}

/// The drag-stress coordinate of [`Coordinates::Hardening`]: where R0,
/// R1, D1, m1, m2 sit in θ, and the reference plastic work W* (Pa), the
/// median over the runs of the work ∫ τ dγ their records put through the
/// fluid. The sampler walks ln Z* with
///
/// Z* = R1 (1 − e^(−m1 W*)) + R0 e^(−m1 W*) + D1 (1 − e^(−m2 W*)),
///
/// increasing in R1 at fixed others, so R1 follows from Z*; points with
/// Z* ≤ R0 e^(−m1 W*) + D1 (1 − e^(−m2 W*)) have no positive R1 and lie
/// outside the support. ln |∂ ln θ / ∂ coordinates| = ln Z* − ln R1 −
/// ln(1 − e^(−m1 W*)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hardening {
    r0: usize,
    r1: usize,
    d1: usize,
    m1: usize,
    m2: usize,
    pub work: f64,
}

impl Hardening {
    /// The reference work of `runs`: the median of each record's ∫ τ dγ
    /// (trapezoids); `None` where that is not a positive number.
    pub fn reference_work(runs: &[crate::data::RunData]) -> Option<f64> {
        let mut works: Vec<f64> = runs
            .iter()
            .map(|r| {
                r.tau
                    .windows(2)
                    .zip(r.gamma.windows(2))
                    .map(|(t, g)| 0.5 * (t[0] + t[1]) * (g[1] - g[0]))
                    .sum::<f64>()
            })
            .collect();
        works.sort_by(f64::total_cmp);
        let n = works.len();
        let median = match n {
            0 => return None,
            _ if n % 2 == 1 => works[n / 2],
            _ => 0.5 * (works[n / 2 - 1] + works[n / 2]),
        };
        (median.is_finite() && median > 0.0).then_some(median)
    }

    /// 1 − e^(−m W*) for ln m = `log_m`.
    fn hardened(&self, log_m: f64) -> f64 {
        -(-log_m.exp() * self.work).exp_m1()
    }

    /// ln θ of R0, D1, R1 from the coordinates `x`, into `log`.
    fn log_theta(&self, x: &[f64], log: &mut [f64]) {
        (log[self.r0], log[self.d1]) = parts(x[self.r0], x[self.d1]);
        let (e1, e2) = (self.hardened(x[self.m1]), self.hardened(x[self.m2]));
        let r1 =
            (x[self.r1].exp() - log[self.r0].exp() * (1.0 - e1) - log[self.d1].exp() * e2) / e1;
        log[self.r1] = if r1 > 0.0 && r1.is_finite() { r1.ln() } else { f64::NEG_INFINITY };
    }

    /// The coordinates of ln θ `log`, into `x` (inverse of [`Self::log_theta`]).
    fn coordinates(&self, log: &[f64], x: &mut [f64]) {
        let (a, b) = (log[self.r0], log[self.d1]);
        (x[self.r0], x[self.d1]) = sum_and_share(a, b);
        let (e1, e2) = (self.hardened(log[self.m1]), self.hardened(log[self.m2]));
        x[self.r1] = (log[self.r1].exp() * e1 + a.exp() * (1.0 - e1) + b.exp() * e2).ln();
    }

    /// ln |∂ ln θ / ∂ coordinates| at `x`, given its ln θ `log`.
    fn log_jacobian(&self, x: &[f64], log: &[f64]) -> f64 {
        x[self.r1] - log[self.r1] - self.hardened(x[self.m1]).ln()
    }
}

/// The layout of a posterior's points.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    /// Every coordinate's name, in order.
    pub names: Vec<String>,
    /// The run ids, in the order of their σ (and ρ).
    pub runs: Vec<String>,
    pub theta: Range<usize>,
    /// The gas-spring stiffness (empty unless that term is on).
    pub spring: Range<usize>,
    /// A force offset per run (empty unless that term is on).
    pub offset: Range<usize>,
    /// Everything before the noise: θ and the terms, which the MAP search
    /// fits while it profiles the noise out.
    pub fitted: Range<usize>,
    /// The noise parameters: block p holds parameter p of every run.
    pub noise: Range<usize>,
    pub noise_parameters: &'static [Parameter],
    /// Where each pair of R1 and D1 sits in θ when they are walked as
    /// saturation and share (one pair, or one per anchor of the curves).
    share: Vec<(usize, usize)>,
    /// The drag stress walked in [`Coordinates::Hardening`], one per B-P
    /// parameter set (one, or one per anchor of the curves; set by
    /// [`Self::harden`]); where any is set, `share` is not walked but kept
    /// for the MAP search ([`Self::searched`]).
    hardening: Vec<Hardening>,
    /// The θ coordinates walked as ln(θ − floor) (θ's position, the
    /// floor: [`ParameterModel::floors`]), so that a posterior that presses
    /// the lower end of a parameter's range (on the measured records
    /// Bouc-Wen's n at 1 at 0.25 and 0.5 A, Spencer's k0 at 0.01 N/m) meets a
    /// tail that thins like e^u rather than a wall the walkers pile against.
    /// A negative floor −c walks ln(θ + c) (`DamperLaw::shifted`): a lower
    /// tail the records leave to the prior, short in that coordinate.
    floors: Vec<(usize, f64)>,
}

/// ln(1 + eᵛ), without overflow.
fn softplus(v: f64) -> f64 {
    v.max(0.0) + (-v.abs()).exp().ln_1p()
}

/// ln(a + b) and ln(b/a) of `log_a` = ln a, `log_b` = ln b: a sum and a
/// share (Jacobian 1).
fn sum_and_share(log_a: f64, log_b: f64) -> (f64, f64) {
    (log_a.max(log_b) + softplus(-(log_a - log_b).abs()), log_b - log_a)
}

/// ln θ of θ = floor + eᵘ, without overflow (u itself for a floor of 0);
/// for a negative floor −c, −∞ (outside the support) at u ≤ ln c.
fn above_floor(u: f64, floor: f64) -> f64 {
    if floor < 0.0 {
        let d = (-floor).ln() - u;
        return if d < 0.0 { u + (-d.exp_m1()).ln() } else { f64::NEG_INFINITY };
    }
    match floor > 0.0 {
        true => floor.ln() + softplus(u - floor.ln()),
        false => u,
    }
}

/// u = ln(θ − floor) of ln θ = `log` (inverse of [`above_floor`]); a θ at
/// a positive floor, where a start may be clamped to its range, is placed
/// a relative 1e-9 above it.
fn below_floor(log: f64, floor: f64) -> f64 {
    if floor < 0.0 {
        return (-floor).ln() + softplus(log - (-floor).ln());
    }
    match floor > 0.0 {
        true => floor.ln() + (log - floor.ln()).exp_m1().max(1e-9).ln(),
        false => log,
    }
}

/// ln a and ln b of their sum and share (inverse of [`sum_and_share`]).
fn parts(sum: f64, share: f64) -> (f64, f64) {
    (sum - softplus(share), sum - softplus(-share))
}

impl Layout {
    pub fn new(
        model: &ParameterModel,
        runs: &[String],
        noise: &dyn NoiseModel,
        coordinates: Coordinates,
        terms: &ModelTerms,
    ) -> Layout {
        let nt = model.names().len();
        let nr = runs.len();
        let ns = usize::from(terms.gas_spring);
        let no = if terms.force_offset { nr } else { 0 };
        let nf = nt + ns + no;
        let noise_parameters = noise.parameters();
        let mut names: Vec<String> = model.names().iter().map(|s| s.to_string()).collect();
        names.extend(std::iter::repeat_n("gas_spring_n_per_m".to_string(), ns));
        names.extend(runs.iter().take(no).map(|r| format!("force_offset_n_{r}")));
        for p in noise_parameters {
            names.extend(runs.iter().map(|r| format!("{}_{r}", p.name)));
        }
        Layout {
            names,
            runs: runs.to_vec(),
            theta: 0..nt,
            spring: nt..nt + ns,
            offset: nt + ns..nf,
            fitted: 0..nf,
            noise: nf..nf + nr * noise_parameters.len(),
            noise_parameters,
            share: match coordinates {
                Coordinates::Log => Vec::new(),
                // until [`Self::harden`] knows the records' work
                Coordinates::SaturationShare | Coordinates::Hardening => model.saturation_pairs(),
            },
            hardening: Vec::new(),
            floors: model.floors(),
        }
    }

    /// The reference plastic work W* of the hardening coordinates, where
    /// the layout has them.
    pub fn reference_work(&self) -> Option<f64> {
        self.hardening.first().map(|h| h.work)
    }

    /// Walks the drag stress after plastic work `work` (Pa) in place of
    /// ln R1 ([`Coordinates::Hardening`]), for the per-current parameters
    /// of the B-P law or of a law built around its element
    /// ([`ParameterModel::has_bp_element`]), and for each anchor of the
    /// current curves (`R0_low` … and `R0_high` …, the same W*); other
    /// models, or no work, keep the saturation-share coordinates.
    pub fn harden(&mut self, model: &ParameterModel, work: Option<f64>) {
        let Some(work) = work else { return };
        let at = |anchor: &str| {
            let i = |n: &str| model.index(&format!("{n}{anchor}"));
            Hardening { r0: i("R0"), r1: i("R1"), d1: i("D1"), m1: i("m1"), m2: i("m2"), work }
        };
        self.hardening = match model {
            _ if model.has_bp_element() => vec![at("")],
            ParameterModel::CurrentCurves { .. } => vec![at("_low"), at("_high")],
            _ => Vec::new(),
        };
    }

    /// The layout the MAP search walks: this one, but saturation-share
    /// coordinates in place of [`Coordinates::Hardening`] (from a start far
    /// from the optimum, m1 W* may be small, where R1 follows from the
    /// drag stress ill-conditioned: Levenberg-Marquardt crawled, 36 s
    /// against 3 s on the measured 1 A runs).
    pub fn searched(&self) -> Option<Layout> {
        (!self.hardening.is_empty()).then(|| Layout { hardening: Vec::new(), ..self.clone() })
    }

    /// ln |∂ ln θ / ∂ coordinates| at the sampler's coordinates `x`: what
    /// the priors, densities of ln θ, need to be densities of the
    /// coordinates (0 but for [`Coordinates::Hardening`] and a law's
    /// parameters walked above their floors).
    pub fn log_jacobian(&self, x: &[f64], log_theta: &[f64]) -> f64 {
        let floors: f64 = self.floors.iter().map(|&(i, _)| x[i] - log_theta[i]).sum();
        floors + self.hardening.iter().map(|h| h.log_jacobian(x, log_theta)).sum::<f64>()
    }

    /// Residuals whose squares add −2 × the floors' part of
    /// [`Self::log_jacobian`] to a least-squares search's −2 ln p: √(2 (ln θ
    /// − u)) for each coordinate walked above its floor (ln θ ≥ u there).
    /// Without them the search would seek the mode of ln θ's density, at
    /// the floor where the posterior presses it, not the coordinates' mode
    /// the sampler and the Laplace approximation need. A shifted
    /// coordinate's part (a negative floor: u ≥ ln θ) is a gain, which no
    /// square adds: 0 here, and the search finds that coordinate's mode in
    /// ln θ; Newton's method then climbs to the sampler's mode (`laplace`).
    pub fn floor_residuals(&self, x: &[f64], log_theta: &[f64]) -> Vec<f64> {
        self.floors.iter().map(|&(i, _)| (2.0 * (log_theta[i] - x[i]).max(0.0)).sqrt()).collect()
    }

    /// The noise parameter at coordinate `i` (in the noise block), and its run.
    fn noise_at(&self, i: usize) -> (Parameter, usize) {
        let nr = self.runs.len().max(1);
        let offset = i - self.noise.start;
        (self.noise_parameters[offset / nr], offset % nr)
    }

    /// Run `j`'s noise parameters at `x` (sampler coordinates or SI,
    /// whichever `x` is), in the model's order.
    pub fn noise_values(&self, x: &[f64], j: usize) -> NoiseValues {
        let nr = self.runs.len();
        let mut v = [0.0; MAX_PARAMETERS];
        for p in 0..self.noise_parameters.len() {
            v[p] = x[self.noise.start + p * nr + j];
        }
        v
    }

    /// The noise of a run none of `runs` is, pooled from theirs at `x` (SI):
    /// each parameter as its [`crate::noise::Pool`] says.
    pub fn pooled_noise(&self, x: &[f64], runs: &[usize]) -> NoiseValues {
        let mut v = [0.0; MAX_PARAMETERS];
        for (p, parameter) in self.noise_parameters.iter().enumerate() {
            let values: Vec<f64> =
                runs.iter().map(|&j| x[self.noise.start + p * self.runs.len() + j]).collect();
            v[p] = parameter.pool.of(&values);
        }
        v
    }

    /// The noise of a run at `current_a` from the runs `others` at point
    /// `x` (SI), every run's current in `run_currents`: where they were
    /// measured at one current, or the currents are not known, all of
    /// them pooled. Otherwise the runs at each current
    /// are pooled, and a current between two calibrated ones gets each
    /// noise parameter interpolated linearly in the current between the
    /// two nearest (a damper's misfit grows with its force, and so with the
    /// current); a calibrated current its own runs' pool; a current
    /// outside the calibrated ones that of the nearest, not extrapolated.
    pub fn noise_at_current(
        &self,
        x: &[f64],
        others: &[usize],
        run_currents: &[f64],
        current_a: f64,
    ) -> NoiseValues {
        let known = run_currents.len() == self.runs.len();
        let mut levels: Vec<f64> = match known {
            true => others.iter().map(|&i| run_currents[i]).collect(),
            false => Vec::new(),
        };
        levels.sort_by(f64::total_cmp);
        levels.dedup_by(|a, b| crate::data::same_current(*a, *b));
        if levels.len() < 2 {
            return self.pooled_noise(x, others);
        }
        let at = |level: f64| {
            let runs: Vec<usize> = others
                .iter()
                .copied()
                .filter(|&i| crate::data::same_current(run_currents[i], level))
                .collect();
            self.pooled_noise(x, &runs)
        };
        let above =
            levels.partition_point(|&c| c < current_a && !crate::data::same_current(c, current_a));
        match above {
            0 => at(levels[0]),
            k if k == levels.len() => at(levels[k - 1]),
            k if crate::data::same_current(levels[k], current_a) => at(levels[k]),
            k => {
                let (lo, hi) = (levels[k - 1], levels[k]);
                let (a, b) = (at(lo), at(hi));
                let w = (current_a - lo) / (hi - lo);
                std::array::from_fn(|p| a[p] + w * (b[p] - a[p]))
            }
        }
    }

    /// Names of the sampler's coordinates, for messages.
    pub fn coordinate_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .names
            .iter()
            .enumerate()
            .map(|(i, n)| match i {
                _ if self.noise.contains(&i) => self.noise_at(i).0.transform.label(n),
                _ if self.linear(i) => n.clone(),
                _ => format!("ln {n}"),
            })
            .collect();
        for &(i, floor) in &self.floors {
            names[i] = match floor < 0.0 {
                true => format!("ln ({} + {})", self.names[i], -floor),
                false => format!("ln ({} − {floor})", self.names[i]),
            };
        }
        for h in &self.hardening {
            let (r0, d1) = (&self.names[h.r0], &self.names[h.d1]);
            // "_low", "_high" for the curves' anchors; "" for one parameter set
            let anchor = self.names[h.r1].strip_prefix("R1").unwrap_or_default();
            names[h.r0] = format!("ln ({r0} + {d1})");
            names[h.d1] = format!("ln ({d1} / {r0})");
            names[h.r1] = format!("ln (R{anchor} + D{anchor} after {:.3e} Pa of work)", h.work);
        }
        if self.hardening.is_empty() {
            for &(r1, d1) in &self.share {
                let (a, b) = (&self.names[r1], &self.names[d1]);
                names[r1] = format!("ln ({a} + {b})");
                names[d1] = format!("ln ({b} / {a})");
            }
        }
        names
    }

    /// ln θ at the sampler's coordinates `x` (θ first).
    pub fn log_theta(&self, x: &[f64]) -> Vec<f64> {
        let mut log = x[self.theta.clone()].to_vec();
        for h in &self.hardening {
            h.log_theta(x, &mut log);
        }
        if self.hardening.is_empty() {
            for &(r1, d1) in &self.share {
                (log[r1], log[d1]) = parts(x[r1], x[d1]);
            }
        }
        for &(i, floor) in &self.floors {
            log[i] = above_floor(x[i], floor);
        }
        log
    }

    /// The sampler's θ coordinates of ln θ (inverse of [`Self::log_theta`]).
    pub fn theta_coordinates(&self, log_theta: &[f64]) -> Vec<f64> {
        let mut x = log_theta.to_vec();
        for h in &self.hardening {
            h.coordinates(log_theta, &mut x);
        }
        if self.hardening.is_empty() {
            for &(r1, d1) in &self.share {
                (x[r1], x[d1]) = sum_and_share(log_theta[r1], log_theta[d1]);
            }
        }
        for &(i, floor) in &self.floors {
            x[i] = below_floor(log_theta[i], floor);
        }
        x
    }

    pub fn dim(&self) -> usize {
        self.names.len()
    }

    /// The names of θ.
    pub fn theta_names(&self) -> &[String] {
        &self.names[self.theta.clone()]
    }

    /// Whether `name` is a noise coordinate (σ, ρ, … of a run).
    pub fn is_noise(&self, name: &str) -> bool {
        self.names.iter().position(|n| n == name).is_some_and(|i| i >= self.fitted.end)
    }

    /// Whether coordinate `i` is walked as it is (the terms), not through a
    /// logarithm.
    fn linear(&self, i: usize) -> bool {
        self.spring.contains(&i) || self.offset.contains(&i)
    }

    /// The gas-spring stiffness (N/m) and the force offset of run `j` (N) at
    /// `x` (sampler coordinates or SI: the terms are the same in both); 0
    /// for a term that is off.
    pub fn terms(&self, x: &[f64], j: usize) -> (f64, f64) {
        let spring = if self.spring.is_empty() { 0.0 } else { x[self.spring.start] };
        let offset = if self.offset.is_empty() { 0.0 } else { x[self.offset.start + j] };
        (spring, offset)
    }

    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The names the MAP search fits for run `j` alone: θ, the gas spring
    /// and that run's force offset (the terms that are on).
    pub fn fitted_names_of_run(&self, j: usize) -> impl Iterator<Item = &str> {
        let own = self.offset.start + j;
        self.fitted
            .clone()
            .filter(move |i| !self.offset.contains(i) || *i == own)
            .map(|i| self.names[i].as_str())
    }

    /// The position of run `id` among the runs.
    pub fn run_index(&self, id: &str) -> Option<usize> {
        self.runs.iter().position(|r| r == id)
    }

    /// How coordinate `i` (after θ) maps to SI units: `None` as it is.
    fn transform(&self, i: usize) -> Option<Transform> {
        if self.noise.contains(&i) {
            Some(self.noise_at(i).0.transform)
        } else if self.linear(i) {
            None
        } else {
            Some(Transform::Log)
        }
    }

    /// A point in SI units (θ, terms, noise) from the sampler's coordinates.
    pub fn to_si(&self, x: &[f64]) -> Vec<f64> {
        let theta = self.log_theta(x).into_iter().map(f64::exp);
        let rest = x
            .iter()
            .enumerate()
            .skip(self.theta.end)
            .map(|(i, v)| self.transform(i).map_or(*v, |t| t.to_si(*v)));
        theta.chain(rest).collect()
    }

    /// The sampler's coordinates of a point in SI units (inverse of [`Self::to_si`]).
    pub fn from_si(&self, si: &[f64]) -> Vec<f64> {
        let log: Vec<f64> = si[self.theta.clone()].iter().map(|v| v.ln()).collect();
        let rest = si
            .iter()
            .enumerate()
            .skip(self.theta.end)
            .map(|(i, v)| self.transform(i).map_or(*v, |t| t.to_coordinate(*v)));
        self.theta_coordinates(&log).into_iter().chain(rest).collect()
    }
}

/// The unit of a coordinate of the posterior, by its name.
pub fn unit_of(name: &str) -> &'static str {
    if let Some(i) = crate::model::PARAM_NAMES.iter().position(|p| *p == name) {
        return crate::model::PARAM_UNITS[i];
    }
    match name {
        "G_field" | "G_zero" => "Pa",
        "saturation_current_a" => "A",
        "coil_lag_s" => "s",
        "gas_spring_n_per_m" => "N/m",
        _ if name.starts_with("force_offset_n_") => "N",
        _ => crate::noise::unit_of(name).unwrap_or(""),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::{NoiseKind, NoiseOptions};

    #[test]
    fn names_ranges_and_maps_agree() {
        let runs = vec!["a".to_string(), "b".to_string()];
        let ar1 = NoiseKind::Ar1.model(&NoiseOptions::default());
        let gaussian = NoiseKind::Gaussian.model(&NoiseOptions::default());
        let l = Layout::new(
            &ParameterModel::PerCurrent,
            &runs,
            ar1.as_ref(),
            Coordinates::Log,
            &ModelTerms::default(),
        );
        assert_eq!(l.dim(), 11);
        assert_eq!(&l.names[7..], ["sigma_a", "sigma_b", "rho_a", "rho_b"]);
        assert_eq!(l.noise, 7..11);
        assert_eq!(l.coordinate_names()[10], "atanh rho_b");
        assert_eq!(
            l.noise_values(&(0..11).map(f64::from).collect::<Vec<_>>(), 1),
            [8.0, 10.0, 0.0, 0.0]
        );
        assert!(l.is_noise("rho_b") && !l.is_noise("G") && !l.is_noise("nope"));
        let x: Vec<f64> = (0..11).map(|i| 0.1 * i as f64 - 0.5).collect();
        let si = l.to_si(&x);
        assert!((si[0] - (-0.5f64).exp()).abs() < 1e-15 && (si[10] - 0.5f64.tanh()).abs() < 1e-15);
        for (a, b) in l.from_si(&si).iter().zip(&x) {
            assert!((a - b).abs() < 1e-12);
        }
        let g = Layout::new(
            &ParameterModel::CurrentLaw { reference_a: 1.0, lag: false },
            &runs,
            gaussian.as_ref(),
            Coordinates::Log,
            &ModelTerms::default(),
        );
        assert_eq!((g.dim(), g.noise.len()), (11, 2));
        let terms = ModelTerms { force_offset: true, gas_spring: true, ..ModelTerms::default() };
        let t = Layout::new(
            &ParameterModel::PerCurrent,
            &runs,
            gaussian.as_ref(),
            Coordinates::Log,
            &terms,
        );
        assert_eq!(&t.names[7..10], ["gas_spring_n_per_m", "force_offset_n_a", "force_offset_n_b"]);
        assert_eq!((t.fitted.clone(), t.noise.clone()), (0..10, 10..12));
        let x: Vec<f64> = (0..12).map(|i| i as f64 - 3.0).collect();
        assert_eq!(t.terms(&x, 1), (4.0, 6.0));
        assert_eq!((t.to_si(&x)[8], t.from_si(&t.to_si(&x))[9]), (5.0, 6.0));
    }

    /// `log_jacobian` of `l` at `x` equals ln |det ∂ ln θ / ∂x| over the
    /// first `n` coordinates (the θ block) by central differences (error
    /// O(h²) ≈ 1e-8).
    fn jacobian_by_differences(l: &Layout, x: &[f64], n: usize) {
        let h = 1e-5;
        let jac = nalgebra::DMatrix::from_fn(n, n, |i, j| {
            let (mut up, mut down) = (x.to_vec(), x.to_vec());
            up[j] += h;
            down[j] -= h;
            (l.log_theta(&up)[i] - l.log_theta(&down)[i]) / (2.0 * h)
        });
        let det = jac.determinant().abs().ln();
        let lj = l.log_jacobian(x, &l.log_theta(x));
        assert!((det - lj).abs() < 1e-6, "finite differences {det}, log_jacobian {lj}");
    }

    /// Saturation-share coordinates: R1 + D1 and ln(D1/R1) at their places,
    /// the map inverts, and its Jacobian determinant is 1 (finite
    /// differences), so densities of ln θ need no correction.
    #[test]
    fn saturation_share_coordinates_invert_with_unit_jacobian() {
        let runs = vec!["a".to_string()];
        let l = Layout::new(
            &ParameterModel::PerCurrent,
            &runs,
            NoiseKind::Gaussian.model(&NoiseOptions::default()).as_ref(),
            Coordinates::SaturationShare,
            &ModelTerms::default(),
        );
        let si = [2e5, 1.2e5, 1.6e5, 3e4, 4e-6, 2e-4, 1.2, 300.0];
        let x = l.from_si(&si);
        assert!(
            (x[2] - (1.9e5f64).ln()).abs() < 1e-12 && (x[3] - (3e4f64 / 1.6e5).ln()).abs() < 1e-12
        );
        for (a, b) in l.to_si(&x).iter().zip(&si) {
            assert!((a / b - 1.0).abs() < 1e-12, "{a} vs {b}");
        }
        let h = 1e-6;
        let at = |du: f64, dv: f64| {
            let mut y = x.clone();
            y[2] += du;
            y[3] += dv;
            let lt = l.log_theta(&y);
            (lt[2], lt[3])
        };
        let (a0, b0) = at(0.0, 0.0);
        let (au, bu) = at(h, 0.0);
        let (av, bv) = at(0.0, h);
        let det = ((au - a0) * (bv - b0) - (av - a0) * (bu - b0)) / (h * h);
        assert!((det - 1.0).abs() < 1e-6, "{det}");
        assert_eq!(l.coordinate_names()[3], "ln (D1 / R1)");
    }

    /// Hardening coordinates: ln(R0 + D1), ln(D1/R0) and ln Z* at their
    /// places (Z* computed here from its formula), the map inverts, and
    /// `log_jacobian` equals ln |det ∂ ln θ / ∂x| by central differences
    /// of the whole θ block (error O(h²) ≈ 1e-8); a point with no positive
    /// R1 maps to ln R1 = −∞.
    #[test]
    fn hardening_coordinates_invert_and_carry_their_jacobian() {
        let runs = vec!["a".to_string()];
        let mut l = Layout::new(
            &ParameterModel::PerCurrent,
            &runs,
            NoiseKind::Gaussian.model(&NoiseOptions::default()).as_ref(),
            Coordinates::Hardening,
            &ModelTerms::default(),
        );
        let w = 4e6;
        l.harden(&ParameterModel::PerCurrent, Some(w));
        for si in [
            [2e5, 5e4, 1.3e5, 2.5e4, 1.2e-8, 2e-3, 0.33, 300.0],
            [2e5, 1.2e5, 0.9e5, 3e4, 4e-6, 2e-4, 1.2, 300.0],
        ] {
            let x = l.from_si(&si);
            let (e1, e2) = (1.0 - (-si[4] * w).exp(), 1.0 - (-si[5] * w).exp());
            let z = si[2] * e1 + si[1] * (1.0 - e1) + si[3] * e2;
            assert!(
                (x[1] - (si[1] + si[3]).ln()).abs() < 1e-12
                    && (x[3] - (si[3] / si[1]).ln()).abs() < 1e-12
                    && (x[2] - z.ln()).abs() < 1e-12
            );
            for (a, b) in l.to_si(&x).iter().zip(&si) {
                assert!((a / b - 1.0).abs() < 1e-9, "{a} vs {b}");
            }
            jacobian_by_differences(&l, &x, 7);
        }
        let mut x = l.from_si(&[2e5, 5e4, 1.3e5, 2.5e4, 1.2e-8, 2e-3, 0.33, 300.0]);
        x[2] = (2.5e4f64).ln();
        assert_eq!(l.log_theta(&x)[2], f64::NEG_INFINITY);
        assert_eq!(l.coordinate_names()[2], "ln (R + D after 4.000e6 Pa of work)");
    }

    /// The layout of `model` for one run with Gaussian noise, in the
    /// hardening coordinates after 4·10⁶ Pa of work.
    fn hardened(model: &ParameterModel) -> Layout {
        let noise = NoiseKind::Gaussian.model(&NoiseOptions::default());
        let runs = vec!["a".to_string()];
        let mut l = Layout::new(
            model,
            &runs,
            noise.as_ref(),
            Coordinates::Hardening,
            &ModelTerms::default(),
        );
        l.harden(model, Some(4e6));
        l
    }

    /// The current curves walk each anchor's stresses in the hardening
    /// coordinates (the same W*): ln(R0_x + D1_x) and ln(D1_x / R0_x) at
    /// their places, the map inverts, and `log_jacobian` (the two anchors'
    /// terms) equals ln |det ∂ ln θ / ∂x| over all 21 curve coordinates.
    #[test]
    fn the_curves_walk_each_anchors_hardening_coordinates() {
        let l = hardened(&ParameterModel::CurrentCurves { low_a: 0.25, high_a: 1.0, lag: false });
        let mut si = vec![2e5, 5e4, 1.3e5, 2.5e4, 1.2e-8, 2e-3, 0.33];
        si.extend([3e5, 1.2e5, 0.9e5, 3e4, 4e-6, 2e-4, 1.2]);
        si.extend([1.1, 0.8, 1.3, 0.9, 1.2, 0.7, 1.05]);
        si.push(300.0);
        let x = l.from_si(&si);
        for (r0, d1) in [(1, 3), (8, 10)] {
            assert!((x[r0] - (si[r0] + si[d1]).ln()).abs() < 1e-12, "{r0}");
            assert!((x[d1] - (si[d1] / si[r0]).ln()).abs() < 1e-12, "{d1}");
        }
        for (a, b) in l.to_si(&x).iter().zip(&si) {
            assert!((a / b - 1.0).abs() < 1e-9, "{a} vs {b}");
        }
        jacobian_by_differences(&l, &x, 21);
        let names = l.coordinate_names();
        assert_eq!(names[8], "ln (R0_high + D1_high)");
        assert_eq!(names[2], "ln (R_low + D_low after 4.000e6 Pa of work)");
        assert!(l.searched().is_some_and(|s| s.coordinate_names()[9] == "ln (R1_high + D1_high)"));
    }

    /// A law built around the B-P element (`bp-viscous`, `bp-spencer`)
    /// walks its first seven parameters as the B-P law does (the hardening
    /// coordinates, no floors) and the others above their floors: the map
    /// inverts, ln(R0 + D1) and ln(c0 − floor) sit at their places, and
    /// `log_jacobian` equals ln |det ∂ ln θ / ∂x| over the whole θ block.
    /// Laws without the element keep ln(θ − floor) throughout.
    #[test]
    fn a_law_around_the_bp_element_walks_its_hardening_coordinates() {
        use crate::laws::LawKind;
        for (law, si) in [
            (LawKind::BpViscous, vec![2e5, 5e4, 1.3e5, 2.5e4, 1.2e-8, 2e-3, 0.33, 250.0, 300.0]),
            (
                LawKind::BpSpencer,
                vec![2e5, 1.2e5, 0.9e5, 3e4, 4e-6, 2e-4, 1.2, 250.0, 4e4, 2e3, 300.0],
            ),
        ] {
            let model = ParameterModel::Law { law };
            assert!(model.has_bp_element(), "{law:?}");
            let l = hardened(&model);
            let x = l.from_si(&si);
            // bp-viscous's dashpot above its floor, bp-spencer's shifted
            let c0 = match law {
                LawKind::BpSpencer => si[7] + 1e3,
                _ => si[7] - law.law().parameters()[7].range.0,
            };
            assert!((x[1] - (si[1] + si[3]).ln()).abs() < 1e-12);
            assert!((x[7] - c0.ln()).abs() < 1e-12, "{law:?}: {}", x[7]);
            assert!((x[6] - si[6].ln()).abs() < 1e-12, "n walks ln n, as in the B-P law");
            for (a, b) in l.to_si(&x).iter().zip(&si) {
                assert!((a / b - 1.0).abs() < 1e-9, "{law:?}: {a} vs {b}");
            }
            jacobian_by_differences(&l, &x, si.len() - 1);
            assert_eq!(l.coordinate_names()[1], "ln (R0 + D1)");
            if law == LawKind::BpSpencer {
                assert_eq!(l.coordinate_names()[7], "ln (c0 + 1000)");
                // a dashpot far below the shift: the map inverts, the
                // Jacobian holds; at or below the wall u = ln c, no θ
                let mut thin = si.clone();
                thin[7] = 20.0;
                let x = l.from_si(&thin);
                assert!((l.to_si(&x)[7] / 20.0 - 1.0).abs() < 1e-9);
                jacobian_by_differences(&l, &x, si.len() - 1);
                let mut wall = x.clone();
                wall[7] = 1e3f64.ln();
                assert_eq!(l.log_theta(&wall)[7], f64::NEG_INFINITY);
            }
        }
        for law in [LawKind::Spencer, LawKind::BoucWen, LawKind::Bingham] {
            let model = ParameterModel::Law { law };
            assert!(!model.has_bp_element() && model.saturation_pairs().is_empty(), "{law:?}");
            assert_eq!(model.floors().len(), law.law().parameters().len());
        }
    }

    /// Another law's parameters walk ln(θ − floor), the floor the lower
    /// end of each one's range: u = ln(θ − floor) computed here directly,
    /// the map inverts (also a parameter a hair above its floor), its
    /// log-Jacobian is ln |det ∂ ln θ / ∂u| by central differences, and a
    /// θ clamped to its floor maps just above it, inside the support.
    #[test]
    fn a_laws_parameters_walk_above_their_floors() {
        use crate::laws::LawKind;
        let runs = vec!["a".to_string()];
        let model = ParameterModel::Law { law: LawKind::BoucWen };
        let l = Layout::new(
            &model,
            &runs,
            NoiseKind::Gaussian.model(&NoiseOptions::default()).as_ref(),
            Coordinates::Log,
            &ModelTerms::default(),
        );
        let floors: Vec<f64> =
            LawKind::BoucWen.law().parameters().iter().map(|p| p.range.0).collect();
        assert_eq!(floors[4], 1.0, "n's floor");
        for si in
            [[4.9e3, 1.06e3, 2.8e3, 63.0, 2.4, 2e3], [3.3e3, 590.0, 8.3e3, 9.8, 1.0004, 900.0]]
        {
            let x = l.from_si(&si);
            for k in 0..5 {
                assert!((x[k] - (si[k] - floors[k]).ln()).abs() < 1e-9, "{k}: {}", x[k]);
            }
            for (a, b) in l.to_si(&x).iter().zip(&si) {
                assert!((a / b - 1.0).abs() < 1e-12, "{a} vs {b}");
            }
            jacobian_by_differences(&l, &x, 5);
        }
        let x = l.from_si(&[4.9e3, 1.06e3, 2.8e3, 63.0, 1.0, 2e3]);
        assert!(x[4].is_finite() && l.to_si(&x)[4] > 1.0);
        assert_eq!(l.coordinate_names()[4], "ln (n − 1)");
        let bp = Layout::new(
            &ParameterModel::PerCurrent,
            &runs,
            NoiseKind::Gaussian.model(&NoiseOptions::default()).as_ref(),
            Coordinates::Log,
            &ModelTerms::default(),
        );
        assert_eq!(bp.from_si(&[2e5, 1e5, 2e5, 3e4, 1e-5, 1e-3, 0.6, 1e3])[6], 0.6f64.ln());
    }
}
