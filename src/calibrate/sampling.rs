//! One run of the sampler on a posterior, as a calibration and each
//! held-out calibration of leave-one-out make it: run until converged or
//! told, convergence judged on the SI parameters, then the burn-in, the
//! sample in SI units and its diagnostics.

use std::time::Instant;

use crate::error::Result;
use crate::posterior::{Draws, Posterior, PosteriorSample};
use crate::sampler::{Chains, Diagnostics, Observer, RunControl, Sampler};

/// A posterior sampled.
pub struct Sampled {
    /// The chains in the sampler's coordinates.
    pub chains: Chains,
    /// The same chains in SI units.
    pub sample: PosteriorSample,
    /// Diagnostics in SI units after the burn-in.
    pub diagnostics: Diagnostics,
    /// Wall time of the sampling (s).
    pub seconds: f64,
    /// The step at which R̂, ESS and the chains' length in τ first held
    /// (`None`: they never did, or the run was not run to convergence).
    pub first_held: Option<usize>,
}

impl Sampled {
    /// The draws after the burn-in, thinned by τ_max.
    pub fn draws(&self) -> Draws {
        Draws::after(self.diagnostics.burn_in, self.diagnostics.tau_max)
    }
}

/// Steps `sampler` on `posterior` until `control` says stop, telling
/// `observers`; convergence is judged on the SI sample after a burn-in of
/// `burn_in` steps (0: the rule of the diagnostics, 3 τ_max of the
/// sampler's coordinates).
pub fn run(
    posterior: &Posterior,
    sampler: &mut Sampler<Posterior>,
    control: &RunControl,
    burn_in: usize,
    observers: &mut [&mut dyn Observer],
) -> Result<Sampled> {
    let clock = Instant::now();
    let layout = &posterior.layout;
    let adaptive = sampler.adaptive();
    let burn_in_of = |chains: &Chains| {
        if burn_in > 0 {
            burn_in
        } else {
            Diagnostics::burn_in_rule(chains, adaptive)
        }
    };
    let currents: Vec<f64> = posterior.runs.iter().map(|r| r.current_a).collect();
    let diagnose = |chains: &Chains| {
        PosteriorSample::from_coordinates(layout, posterior.model, chains, Vec::new())
            .diagnostics(burn_in_of(chains))
    };
    let control = RunControl { names: layout.names.clone(), ..control.clone() };
    sampler.run_until(&control, observers, &diagnose)?;
    let chains = sampler.chains.clone();
    let seconds = clock.elapsed().as_secs_f64();
    let sample = PosteriorSample::from_coordinates(layout, posterior.model, &chains, currents);
    let mut diagnostics = sample.diagnostics(burn_in_of(&chains));
    diagnostics
        .warnings
        .extend(crate::sampler::stranded::history(&chains).iter().map(|r| r.message()));
    Ok(Sampled { chains, sample, diagnostics, seconds, first_held: sampler.first_held() })
}
