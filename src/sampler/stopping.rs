//! The stopping rule of a run that stops once converged: whether it has,
//! and, where it has not, what it waits for — one quantity of one
//! coordinate, its value and its target, said at every check.
//!
//! Converged (Vehtari et al. 2021, with emcee's length rule): every R̂
//! below [`RHAT_THRESHOLD`], no drift of a mean or a spread left after burn-in
//! ([`super::drift`]), every bulk and tail ESS at least the target, and
//! the chains at least `min_tau_multiple` τ_max long after burn-in.
//! A run told to confirm ([`RunControl::confirm`]: a posterior far from its
//! Laplace approximation) goes on to twice the step at which that first
//! held, and stops at the first check from there at which it holds again.

use std::fmt;

use super::diagnostics::{Diagnostics, MIN_TAU_MULTIPLE, RHAT_THRESHOLD};
use super::drift::{Moment, DRIFT_Z};

/// How long to run.
#[derive(Clone, Debug)]
pub struct RunControl {
    /// Run until this many steps in total (including steps already taken).
    pub max_steps: usize,
    /// Stop earlier once converged (see [`unmet`]), checked
    /// at the steps [`RunControl::checks_at`] names. `false`: exactly
    /// `max_steps`.
    pub until_converged: bool,
    /// The shortest interval between convergence checks.
    pub check_every: usize,
    /// Convergence also needs this bulk and tail ESS for every coordinate.
    pub min_ess: f64,
    /// ... and the chains this many τ_max long after burn-in
    /// ([`Diagnostics::converged_for`]).
    pub min_tau_multiple: f64,
    /// Once converged, go on to twice that step and check again there
    /// : for a posterior far from its Laplace
    /// approximation, whose far ends the walkers fill slowly.
    pub confirm: bool,
    /// The coordinates' names, for what the rule says it waits for (by
    /// index where empty).
    pub names: Vec<String>,
}

impl RunControl {
    /// Whether convergence is checked after step `step`: every
    /// `check_every` steps while the chain is short, then at an interval
    /// that doubles whenever the chain has grown to 16 intervals (a check
    /// reads every draw, so checking at a fixed interval would cost time
    /// quadratic in the chain's length: on a 2 360-step calibration the
    /// checks took three quarters of the wall time). The interval stays
    /// within 1/8 of the chain, so a run stops at most 1/8 later than it
    /// could have. A function of the step alone, so a resumed run checks
    /// where an uninterrupted one does.
    pub fn checks_at(&self, step: usize) -> bool {
        let mut interval = self.check_every.max(1);
        while step >= 16 * interval {
            interval *= 2;
        }
        step.is_multiple_of(interval)
    }

    pub fn fixed(steps: usize) -> Self {
        RunControl {
            max_steps: steps,
            until_converged: false,
            check_every: 500,
            min_ess: 0.0,
            min_tau_multiple: MIN_TAU_MULTIPLE,
            confirm: false,
            names: Vec::new(),
        }
    }
}

/// What a run that has not converged waits for: the first condition of
/// the rule that fails, in the order R̂, drift, ESS, length, confirmation.
#[derive(Clone, Debug, PartialEq)]
pub enum Waiting {
    /// Too few draws after burn-in to estimate an ESS yet.
    Draws,
    /// The largest R̂, of `coordinate`.
    RHat { coordinate: String, value: f64 },
    /// The draws still drift: `coordinate`'s mean (or spread) moved by
    /// `z` standard errors from the first quarter of the draws after step
    /// `from` (the burn-in, or a third of the chain where that is
    /// shorter) to their last half ([`super::drift`]).
    Drift { coordinate: String, moment: Moment, z: f64, from: usize },
    /// The smallest bulk or tail ESS, of `coordinate`.
    Ess { coordinate: String, value: f64, target: f64 },
    /// The chains are `kept` steps long after burn-in; the rule asks for
    /// `multiple` τ_max.
    Length { kept: usize, multiple: f64, tau_max: f64 },
    /// R̂, ESS and length first held at step `first`; the run goes on to
    /// step `until` to check them again.
    Confirmation { first: usize, until: usize },
}

impl fmt::Display for Waiting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Waiting::Draws => write!(f, "too few draws after burn-in to estimate an ESS"),
            Waiting::RHat { coordinate, value } if value.is_nan() => write!(
                f,
                "R̂ of {coordinate} cannot be computed: its draws do not spread (walkers stuck; target < {RHAT_THRESHOLD})"
            ),
            Waiting::RHat { coordinate, value } => {
                write!(f, "R̂ of {coordinate} is {value:.4} (target < {RHAT_THRESHOLD})")
            }
            Waiting::Drift { coordinate, moment: Moment::Mean, z, from } => write!(
                f,
                "the draws of {coordinate} still drift: their mean moved by {z:.1} standard errors from the first quarter of the draws after step {from} to their last half (target within ±{DRIFT_Z}; the walkers have not forgotten their start)"
            ),
            Waiting::Drift { coordinate, moment: Moment::Spread, z, from } => write!(
                f,
                "the draws of {coordinate} still {}: their spread moved by {z:.1} standard errors from the first quarter of the draws after step {from} to their last half (target within ±{DRIFT_Z}; the walkers started {} than the posterior and have not yet filled it)",
                if *z > 0.0 { "widen" } else { "narrow" },
                if *z > 0.0 { "narrower" } else { "wider" }
            ),
            Waiting::Ess { coordinate, value, target } => {
                write!(f, "ESS of {coordinate} is {value:.0} (target ≥ {target:.0})")
            }
            Waiting::Length { kept, multiple, tau_max } => write!(
                f,
                "the chains are {kept} steps long after burn-in (target {multiple} τ_max = {:.0}, τ_max {tau_max:.1})",
                (multiple * tau_max).ceil()
            ),
            Waiting::Confirmation { first, until } => write!(
                f,
                "R̂ and ESS first held at step {first}; the posterior is far from its Laplace approximation, so the run goes on to step {until} and checks them again there"
            ),
        }
    }
}

/// The first condition of the rule (without confirmation) that `diag`
/// fails, coordinates named by `names` (by index where it has none).
pub fn unmet(
    diag: &Diagnostics,
    min_ess: f64,
    tau_multiple: f64,
    names: &[String],
) -> Option<Waiting> {
    let name = |i: usize| names.get(i).cloned().unwrap_or_else(|| format!("coordinate {i}"));
    // the worst R̂ (a NaN R̂ counts as failing)
    let rhat = diag
        .coordinates
        .iter()
        .enumerate()
        .filter(|(_, c)| !(c.r_hat < RHAT_THRESHOLD))
        .max_by(|a, b| a.1.r_hat.total_cmp(&b.1.r_hat));
    if let Some((i, c)) = rhat {
        return Some(Waiting::RHat { coordinate: name(i), value: c.r_hat });
    }
    if let Some(d) = &diag.drift {
        return Some(Waiting::Drift {
            coordinate: name(d.coordinate),
            moment: d.moment,
            z: d.z,
            from: d.from,
        });
    }
    if diag.coordinates.iter().any(|c| c.ess().is_nan()) {
        return Some(Waiting::Draws);
    }
    let smallest = diag
        .coordinates
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.ess().total_cmp(&b.1.ess()))
        .filter(|(_, c)| c.ess() < min_ess);
    if let Some((i, c)) = smallest {
        return Some(Waiting::Ess { coordinate: name(i), value: c.ess(), target: min_ess });
    }
    let kept = (diag.steps + 1).saturating_sub(diag.burn_in);
    if (kept as f64) < tau_multiple * diag.tau_max {
        return Some(Waiting::Length { kept, multiple: tau_multiple, tau_max: diag.tau_max });
    }
    None
}

impl Diagnostics {
    /// Every R̂ below [`RHAT_THRESHOLD`] and every bulk and tail ESS at
    /// least `min_ess` (Vehtari et al. 2021): the ensembles agree and the
    /// draws are enough for their purpose; and the chains at least
    /// [`MIN_TAU_MULTIPLE`] τ long after burn-in, so that those estimates
    /// rest on more than a few autocorrelation times.
    pub fn converged(&self, min_ess: f64) -> bool {
        self.converged_for(min_ess, MIN_TAU_MULTIPLE)
    }

    /// [`Self::converged`] with the chains at least `tau_multiple` τ_max
    /// long after burn-in ([`unmet`] says which condition fails).
    pub fn converged_for(&self, min_ess: f64, tau_multiple: f64) -> bool {
        unmet(self, min_ess, tau_multiple, &[]).is_none()
    }
}

/// The rule over one run: it remembers the step at which R̂, ESS and
/// length first held, which confirmation counts from.
#[derive(Clone, Debug, Default)]
pub struct Stopping {
    first_held: Option<usize>,
}

impl Stopping {
    /// The check at `step`: `None` to stop, or what the run waits for.
    pub fn check(
        &mut self,
        control: &RunControl,
        step: usize,
        diag: &Diagnostics,
    ) -> Option<Waiting> {
        if let Some(waiting) =
            unmet(diag, control.min_ess, control.min_tau_multiple, &control.names)
        {
            return Some(waiting);
        }
        let first = *self.first_held.get_or_insert(step);
        (control.confirm && step < 2 * first)
            .then_some(Waiting::Confirmation { first, until: 2 * first })
    }

    /// The step at which R̂, ESS and length first held, if they have.
    pub fn first_held(&self) -> Option<usize> {
        self.first_held
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::ParameterDiagnostics;

    fn coordinate(r_hat: f64, ess: f64) -> ParameterDiagnostics {
        ParameterDiagnostics {
            mean: 0.0,
            sd: 1.0,
            q05: -1.6,
            q50: 0.0,
            q95: 1.6,
            ess_bulk: ess,
            ess_tail: ess + 1.0,
            r_hat,
            tau_int: 5.0,
            mcse_mean: 0.05,
        }
    }

    fn diagnostics(steps: usize, coordinates: Vec<ParameterDiagnostics>) -> Diagnostics {
        Diagnostics {
            steps,
            burn_in: 15,
            coordinates,
            tau_max: 5.0,
            acceptance: vec![0.3; 8],
            stuck: vec![],
            drift: None,
            warnings: vec![],
        }
    }

    fn control(confirm: bool) -> RunControl {
        RunControl {
            until_converged: true,
            check_every: 10,
            min_ess: 400.0,
            confirm,
            names: vec!["ln G".into(), "ln n".into()],
            ..RunControl::fixed(5000)
        }
    }

    /// A coordinate whose draws do not spread has no R̂ (NaN): the rule
    /// waits on it and says so, and the largest R̂ is NaN, not the largest
    /// of the others (which read 0.0000 where every coordinate was stuck).
    #[test]
    fn a_coordinate_without_spread_is_named_not_hidden() {
        let stuck = diagnostics(100, vec![coordinate(1.002, 900.0), coordinate(f64::NAN, 900.0)]);
        let w = unmet(&stuck, 400.0, 50.0, &control(false).names).expect("waits");
        assert!(
            w.to_string().contains("R̂ of ln n cannot be computed: its draws do not spread"),
            "{w}"
        );
        assert!(stuck.max_rhat().is_nan());
        use crate::sampler::diagnostics::largest_rhat;
        assert_eq!(largest_rhat([1.002, 1.03]), 1.03);
        assert!(largest_rhat([f64::NAN, 1.03]).is_nan() && largest_rhat([1.03, f64::NAN]).is_nan());
        assert_eq!(largest_rhat([]), 0.0);
    }

    /// Draws that still drift hold a run whose R̂ passes, and the rule
    /// names the coordinate, z, the step the test counts from and the
    /// target; after R̂, before ESS.
    #[test]
    fn a_drift_holds_the_run_and_is_named() {
        use crate::sampler::drift::Drift;
        let mut drifting =
            diagnostics(100, vec![coordinate(1.002, 300.0), coordinate(1.003, 900.0)]);
        drifting.drift = Some(Drift { coordinate: 1, moment: Moment::Mean, z: -5.2, from: 33 });
        let w = unmet(&drifting, 400.0, 10.0, &control(false).names).expect("waits");
        assert_eq!(
            w,
            Waiting::Drift { coordinate: "ln n".into(), moment: Moment::Mean, z: -5.2, from: 33 }
        );
        assert!(w.to_string().contains("the draws of ln n still drift: their mean moved by -5.2 standard errors from the first quarter of the draws after step 33"), "{w}");
        drifting.drift = Some(Drift { coordinate: 0, moment: Moment::Spread, z: 5.7, from: 13 });
        let w = unmet(&drifting, 400.0, 10.0, &control(false).names).expect("waits");
        assert!(w.to_string().contains("the draws of ln G still widen: their spread moved by 5.7 standard errors from the first quarter of the draws after step 13"), "{w}");
        drifting.coordinates[1].r_hat = 1.05;
        assert!(matches!(
            unmet(&drifting, 400.0, 10.0, &control(false).names),
            Some(Waiting::RHat { .. })
        ));
    }

    /// Each condition is named with its coordinate, value and target, in
    /// the rule's order; a run that holds them stops at once unless told
    /// to confirm, then at the first check from twice that step.
    #[test]
    fn the_rule_says_what_it_waits_for_and_stops_when_it_holds() {
        let mut rule = Stopping::default();
        let c = control(false);
        let w = rule.check(
            &c,
            100,
            &diagnostics(100, vec![coordinate(1.002, 900.0), coordinate(1.03, 900.0)]),
        );
        assert_eq!(w, Some(Waiting::RHat { coordinate: "ln n".into(), value: 1.03 }));
        assert!(w.unwrap().to_string().contains("R̂ of ln n is 1.0300 (target < 1.01)"));
        let w = rule.check(
            &c,
            100,
            &diagnostics(100, vec![coordinate(1.002, 300.0), coordinate(1.003, 900.0)]),
        );
        assert_eq!(
            w,
            Some(Waiting::Ess { coordinate: "ln G".into(), value: 300.0, target: 400.0 })
        );
        let w = rule.check(
            &c,
            60,
            &diagnostics(60, vec![coordinate(1.002, 900.0), coordinate(1.003, f64::NAN)]),
        );
        assert_eq!(w, Some(Waiting::Draws));
        // 46 steps after a burn-in of 15 are fewer than 10 τ = 50
        let w = rule.check(
            &c,
            60,
            &diagnostics(60, vec![coordinate(1.002, 900.0), coordinate(1.003, 900.0)]),
        );
        assert_eq!(w, Some(Waiting::Length { kept: 46, multiple: 10.0, tau_max: 5.0 }));
        let good = |s| diagnostics(s, vec![coordinate(1.002, 900.0), coordinate(1.003, 900.0)]);
        assert_eq!(rule.check(&c, 120, &good(120)), None);

        let mut rule = Stopping::default();
        let c = control(true);
        assert_eq!(
            rule.check(&c, 120, &good(120)),
            Some(Waiting::Confirmation { first: 120, until: 240 })
        );
        // a later failure does not move the step it first held at
        assert!(matches!(
            rule.check(
                &c,
                200,
                &diagnostics(200, vec![coordinate(1.02, 900.0), coordinate(1.0, 900.0)])
            ),
            Some(Waiting::RHat { .. })
        ));
        assert_eq!(
            rule.check(&c, 220, &good(220)),
            Some(Waiting::Confirmation { first: 120, until: 240 })
        );
        assert_eq!(rule.check(&c, 240, &good(240)), None);
        assert_eq!(rule.first_held(), Some(120));
    }

    #[test]
    fn convergence_checks_thin_out_as_the_chain_grows() {
        let control =
            RunControl { until_converged: true, check_every: 10, ..RunControl::fixed(5000) };
        let checks: Vec<usize> = (1..=5000).filter(|s| control.checks_at(*s)).collect();
        // every 10 steps below 160, then every 20, 40, 80, 160, 320
        assert_eq!(&checks[..16], &(1..=16).map(|k| 10 * k).collect::<Vec<_>>()[..]);
        assert_eq!(&checks[16..20], &[180, 200, 220, 240]);
        assert!(checks.contains(&2560) && !checks.contains(&2600) && checks.contains(&2880));
        // never more than 1/8 of the chain (nor less than 10 steps) between checks
        for pair in checks.windows(2) {
            assert!(pair[1] - pair[0] <= (pair[0] / 8).max(10), "{pair:?}");
        }
        // 55 checks in 5000 steps instead of 500
        assert_eq!(checks.len(), 16 + 4 * 8 + 7);
    }
}
