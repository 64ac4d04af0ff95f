//! Damper laws: what turns a run's excitation into the force a damper
//! model predicts, one law a file behind one trait, [`DamperLaw`].
//!
//! Every law maps the run's strain history γ(t) (the record's displacement
//! over the gap, smoothed; [`RunData::gamma`]) to the stress τ(t) its force
//! puts on the records' scale (force over the area), so that the noise
//! models, the bands and the stores see one kind of path whatever the law.
//! The Bouc-Wen family is written in force and displacement, as the field
//! writes it: such a law turns γ into x = h γ and its force F into τ = F/A
//! with the run's own geometry, and its parameters keep their units (N,
//! N·s/m, 1/m). A parallel spring and a force offset are no law's: they are
//! the model terms (`[terms]` `gas_spring`, `force_offset`), which any law
//! takes.
//!
//! | question | method |
//! |---|---|
//! | its parameters: names, units, physical range, plausible values (the prior's ±1 sd) | [`DamperLaw::parameters`] |
//! | the stress of up to [`LANES`] parameter sets along a run, in the integrator's lanes | [`DamperLaw::run_lanes`] |
//! | the Euler steps that costs (the step rule's measure of work) | [`DamperLaw::euler_steps`] |
//! | the bound of its tangent stiffness dτ/dγ (errors in variables) | [`DamperLaw::stiffness_bound`] |
//! | where a MAP search may start, from the records | [`DamperLaw::starts`] |
//!
//! **Adding a law**: a file here with a type that implements [`DamperLaw`]
//! (a law with an internal state driven by displacement and velocity, as
//! the Bouc-Wen family, implements [`ode::StateLaw`] instead and gets the
//! lanes, the step control and AVX2 from [`ode`]) and has `const fn new()
//! -> Self`, and its line in the [`registry!`] below, which makes its name a
//! value of `--law` and of `law =` in a settings file. Its tests run the conformance
//! harness of `testing` (lanes against one at a time, the integrator's
//! order, the parameters recovered from its own virtual records).

pub mod bingham;
pub mod bodner_partom;
pub mod bouc_wen;
pub mod bp_spencer;
pub mod bp_viscous;
pub mod ode;
pub mod spencer;

use serde::{Deserialize, Serialize};

use crate::data::RunData;
use crate::model::{IntegrationError, Integrator, Params, LANES};

/// The most parameters a law has.
pub const MAX_LAW_PARAMETERS: usize = 10;

/// One parameter set of a law, in the order of [`DamperLaw::parameters`]
/// (SI); unused places are 0.
pub type LawValues = [f64; MAX_LAW_PARAMETERS];

/// One parameter of a law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LawParameter {
    pub name: &'static str,
    pub unit: &'static str,
    /// The physical range: the support of the default prior, and what a
    /// parameter set outside of is refused by the integrator.
    pub range: (f64, f64),
    /// Plausible values for an MR damper of the RD-1005-3 class (peak
    /// forces of 0.1–3 kN over strokes of millimetres to centimetres): the
    /// ±1 sd span of the default log-normal prior.
    pub plausible: (f64, f64),
}

/// What a calibration needs of a damper law.
pub trait DamperLaw: Send + Sync + std::fmt::Debug {
    /// Its name in the registry.
    fn kind(&self) -> LawKind;

    /// Its parameters, in the order of every [`LawValues`].
    fn parameters(&self) -> &'static [LawParameter];

    /// Integrates every lane's parameter set along `run` from its initial
    /// state, calling `visit(k, stress)` at every sample `k` with each
    /// lane's stress (Pa). Lanes never interact: a parameter set gives the
    /// same bits in any lane and beside any other. A lane whose parameters
    /// leave their range, or whose integration fails, is reported so; what
    /// it visits after that means nothing.
    fn run_lanes(
        &self,
        integrator: &Integrator,
        params: &[LawValues; LANES],
        run: &RunData,
        visit: &mut dyn FnMut(usize, &[f64; LANES]),
    ) -> [Result<(), IntegrationError>; LANES];

    /// Whether its integration follows the integrator's scheme (explicit
    /// or linearly implicit Euler, the B-P integrators'); a law with its
    /// own scheme (ROS2, [`ode`]) gives the same bits under either, so the
    /// step rule need not study both.
    fn follows_scheme(&self) -> bool {
        true
    }

    /// The order of its integrator's error in the sub-step (1: Euler).
    fn order(&self) -> u32 {
        1
    }

    /// The Euler steps one integration of `params` along `run` takes.
    fn euler_steps(&self, integrator: &Integrator, params: &LawValues, run: &RunData) -> u64;

    /// The largest tangent stiffness dτ/dγ (Pa) the law can show along
    /// `run`: what clips the stiffness that carries the strain's noise into
    /// the stress (errors in variables).
    fn stiffness_bound(&self, params: &LawValues, run: &RunData) -> f64;

    /// Parameter sets a MAP search may start from, given the records' peak
    /// force (N), velocity (m/s) and stroke (m, half the peak-to-peak
    /// displacement), each inside the physical range.
    fn starts_at(&self, force: f64, velocity: f64, stroke: f64) -> Vec<LawValues>;

    /// Parameter sets a MAP search may start from, read off the records of
    /// one current ([`Self::starts_at`] their scales).
    fn starts(&self, runs: &[RunData]) -> Vec<LawValues> {
        let (force, velocity, stroke) = scales(runs);
        self.starts_at(force.max(1e-3), velocity.max(1e-6), stroke.max(1e-6))
    }

    /// Whether the law is built on the B-P element (other than the B-P
    /// law itself), so that the paper's identification also starts it
    /// ([`Self::starts_around`]).
    fn builds_on_bodner_partom(&self) -> bool {
        false
    }

    /// The parameters the sampler walks as u = ln(θ + c) instead of ln(θ −
    /// floor) (`posterior::Layout`): (index, c). For a parameter whose
    /// lower tail the records leave to the prior, trading it against
    /// another (`bp-spencer`'s dashpot c0 against the B-P element's rate
    /// exponent), a tail several units of ln θ long that the walkers fill
    /// only by diffusion; below c it is a thin layer above the wall u =
    /// ln c. None by default.
    fn shifted(&self) -> &'static [(usize, f64)] {
        &[]
    }

    /// Parameter sets a MAP search may start from around the B-P
    /// parameters `bp` the paper's identification found on `runs`: for a
    /// law built on the B-P element; none for another.
    fn starts_around(&self, _bp: &Params, _runs: &[RunData]) -> Vec<LawValues> {
        Vec::new()
    }

    /// A parameter set typical of an RD-1005-3-class damper at 1 A (peak
    /// force 2.7 kN at 0.28 m/s over a 6.75 mm stroke, the virtual stand's
    /// at 400 rpm): the truth `mrbp synth --law` uses by default.
    fn typical(&self) -> LawValues {
        self.starts_at(2700.0, 0.28, 0.00675)[0]
    }

    /// The stress of one parameter set at every sample of `run`.
    fn path(
        &self,
        integrator: &Integrator,
        params: &LawValues,
        run: &RunData,
    ) -> Result<Vec<f64>, IntegrationError> {
        let mut out = vec![0.0; run.time.len()];
        let [first, ..] = self.run_lanes(integrator, &[*params; LANES], run, &mut |k, s| {
            out[k] = s[0];
        });
        first.map(|_| out)
    }

    /// The names of its parameters.
    fn names(&self) -> Vec<&'static str> {
        self.parameters().iter().map(|p| p.name).collect()
    }

    /// Checks that every parameter is finite and inside its range; the
    /// message names the first that is not.
    fn validate(&self, params: &LawValues) -> Result<(), String> {
        for (p, v) in self.parameters().iter().zip(params) {
            let (lo, hi) = p.range;
            if !v.is_finite() || *v < lo || *v > hi {
                return Err(format!(
                    "parameter {} = {v:e} is outside its physical range [{lo:e}, {hi:e}]",
                    p.name
                ));
            }
        }
        Ok(())
    }
}

/// The registry: every law, by the name the command line and the settings
/// files give it.
macro_rules! registry {
    ($($(#[$attr:meta])* $variant:ident => $law:ty,)+) => {
        /// A damper law by name (`--law`, `law =` in a settings file).
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
        #[serde(rename_all = "kebab-case")]
        pub enum LawKind {
            $($(#[$attr])* $variant,)+
        }

        impl LawKind {
            /// The law of this name.
            pub fn law(self) -> &'static dyn DamperLaw {
                match self {
                    $(LawKind::$variant => {
                        static LAW: $law = <$law>::new();
                        &LAW
                    })+
                }
            }

            /// Every law.
            pub const ALL: &'static [LawKind] = &[$(LawKind::$variant,)+];
        }
    };
}

registry! {
    /// The Bodner-Partom viscoplastic law for shear (the paper's): pre-yield
    /// modulus, isotropic and kinematic hardening with inelastic work, rate
    /// sensitivity. The default.
    #[default]
    BodnerPartom => bodner_partom::BodnerPartom,
    /// The B-P law with a dashpot in parallel: a force linear in velocity
    /// beside the fluid's viscoplastic stress.
    BpViscous => bp_viscous::BpViscous,
    /// Bouc-Wen: a dashpot in parallel with a hysteretic element (Wen's
    /// model, normalised: its force amplitude, the inverse of its yield
    /// displacement, its shape and its sharpness).
    BoucWen => ode::Ode<bouc_wen::BoucWen>,
    /// Spencer et al.'s (1997) modified Bouc-Wen model ("phenomenological"):
    /// the Bouc-Wen element and a dashpot c0 and spring k0 moving an
    /// internal displacement y, in series with a dashpot c1.
    Spencer => ode::Ode<spencer::Spencer>,
    /// The B-P law in Spencer et al.'s frame: the fluid's viscoplastic
    /// element in place of the Bouc-Wen element, beside a dashpot c0 and a
    /// spring k0, in series with a dashpot c1.
    BpSpencer => ode::Ode<bp_spencer::BpSpencer>,
    /// Bingham: a dashpot and a yield force of smooth sign (tanh of the
    /// velocity over a smoothing velocity).
    Bingham => ode::Ode<bingham::Bingham>,
}

impl LawKind {
    /// Its name as the command line writes it.
    pub fn name(self) -> String {
        clap::ValueEnum::to_possible_value(&self)
            .map(|v| v.get_name().to_string())
            .unwrap_or_default()
    }

    /// Whether this is the Bodner-Partom law, whose parameters also follow
    /// the coil current in a current law or current curves and which the
    /// paper's identification starts.
    pub fn is_bodner_partom(self) -> bool {
        self == LawKind::BodnerPartom
    }
}

/// The strain rate γ̇ at every sample of `run`: central differences of the
/// strain that drives the model (one-sided at the ends), the velocity of a
/// smooth path through the samples, for the dashpots of a law's force.
pub fn strain_rates(run: &RunData) -> Vec<f64> {
    let (t, g) = (&run.time, &run.gamma);
    let n = t.len();
    (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            if b > a {
                (g[b] - g[a]) / (t[b] - t[a])
            } else {
                0.0
            }
        })
        .collect()
}

/// The plausible centre of each parameter: the geometric middle of its
/// plausible range.
pub fn plausible_centre(p: &LawParameter) -> f64 {
    (p.plausible.0 * p.plausible.1).sqrt()
}

/// `values` with each parameter clamped into its physical range.
pub fn clamped(law: &dyn DamperLaw, mut values: LawValues) -> LawValues {
    for (v, p) in values.iter_mut().zip(law.parameters()) {
        *v = if v.is_finite() { v.clamp(p.range.0, p.range.1) } else { plausible_centre(p) };
    }
    values
}

/// The peak force (N), velocity (m/s) and stroke (m, half the
/// peak-to-peak displacement) of `runs`, the largest of each: the scales a
/// law's starts are read off.
pub fn scales(runs: &[RunData]) -> (f64, f64, f64) {
    let mut out: (f64, f64, f64) = (0.0, 0.0, 0.0);
    for run in runs {
        let force = run.tau.iter().map(|t| (t * run.area_m2).abs()).fold(0.0, f64::max);
        let velocity = strain_rates(run).iter().map(|r| (r * run.gap_m).abs()).fold(0.0, f64::max);
        let (lo, hi) = run
            .gamma
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), g| (a.min(*g), b.max(*g)));
        let stroke = 0.5 * (hi - lo) * run.gap_m;
        out = (out.0.max(force), out.1.max(velocity), out.2.max(stroke));
    }
    out
}

#[cfg(test)]
pub(crate) mod testing;
