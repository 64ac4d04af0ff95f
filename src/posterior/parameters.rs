//! What the θ coordinates of a posterior are, and how they give the B-P
//! parameters of each run: one parameter set for the runs of one current,
//! the current law of [`CurrentLaw`] over several currents, or each
//! parameter its own curve in the current ([`CurrentCurves`]).
//!
//! Every question that depends on that choice (names, priors, parameters at
//! a current, the start of the MAP search, the current an identification
//! starts from) is answered here, so that the rest of the calibration does
//! not branch on it. Model terms for real dampers plug in here too.

use serde::{Deserialize, Serialize};

use super::prior::Prior;
use crate::error::{Error, Result};
use crate::laws::bodner_partom::values_of;
use crate::laws::{LawKind, LawValues};
use crate::model::{CurrentCurves, CurrentLaw, FieldLaw, Params, PARAM_NAMES, PHYSICAL_RANGE};

/// The choice as written in settings files and on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ModelKind {
    /// Seven B-P parameters for the runs of one coil current.
    PerCurrent,
    /// R0, R1, D1 and G as saturating functions of the current, one
    /// posterior from the runs of every current.
    CurrentLaw,
    /// Every parameter its own curve in the current, with an off-state:
    /// its values at two anchor currents and a bend.
    CurrentCurves,
}

impl ModelKind {
    /// Whether one posterior describes several currents.
    pub fn is_law(self) -> bool {
        self != ModelKind::PerCurrent
    }
}

/// Names of a current law's θ coordinates (SI units in outputs).
pub const LAW_NAMES: [&str; 9] =
    ["G_field", "R0", "R1", "D1", "m1", "m2", "n", "saturation_current_a", "G_zero"];

/// The coil's lag τ_c (s), the last θ coordinate of a law whose runs'
/// current varies ([`crate::model::FieldCurrent`]).
pub const LAG_NAME: &str = "coil_lag_s";

/// [`LAW_NAMES`] and the coil's lag.
const LAW_NAMES_LAGGED: [&str; 10] =
    ["G_field", "R0", "R1", "D1", "m1", "m2", "n", "saturation_current_a", "G_zero", LAG_NAME];

/// Names of the current curves' θ coordinates: the parameters at the low
/// anchor current, at the high one, and each curve's bend κ.
pub const CURVE_NAMES: [&str; 21] = [
    "G_low", "R0_low", "R1_low", "D1_low", "m1_low", "m2_low", "n_low", "G_high", "R0_high",
    "R1_high", "D1_high", "m1_high", "m2_high", "n_high", "G_bend", "R0_bend", "R1_bend",
    "D1_bend", "m1_bend", "m2_bend", "n_bend",
];

/// [`CURVE_NAMES`] and the coil's lag.
const CURVE_NAMES_LAGGED: [&str; 22] = [
    "G_low", "R0_low", "R1_low", "D1_low", "m1_low", "m2_low", "n_low", "G_high", "R0_high",
    "R1_high", "D1_high", "m1_high", "m2_high", "n_high", "G_bend", "R0_bend", "R1_bend",
    "D1_bend", "m1_bend", "m2_bend", "n_bend", LAG_NAME,
];

/// The prior of the coil's lag τ_c: log-normal about 10 ms (a damper
/// coil's field settles in 5–30 ms) with a factor-e spread, within
/// [0.1 ms, 1 s].
pub const LAG_PRIOR: Prior =
    Prior::LogNormal { median: 0.01, sd_log: 1.0, lower: 1.0e-4, upper: 1.0 };

/// The prior of each curve's bend κ: ln κ normal about 0 (a straight line in
/// ln p against I) with sd 2, so that ±1 sd puts the middle of the change
/// between 27 % and 73 % of the way between the anchors (ln κ = ∓2), within
/// ln κ ∈ [−6, 6] (5 % and 95 %).
pub const BEND_PRIOR: Prior = Prior::LogNormal {
    median: 1.0,
    sd_log: 2.0,
    lower: 0.002_478_752_176_666_358,
    upper: 403.428_793_492_735_1,
};

/// How θ maps to the parameters of a run's damper law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ParameterModel {
    /// θ = (G, R0, R1, D1, m1, m2, n) of the B-P law for every run.
    PerCurrent,
    /// θ = the parameters of another damper law ([`crate::laws`]) for
    /// every run (of one current).
    Law { law: LawKind },
    /// θ = the current law's [`LAW_NAMES`], with its reference current (A),
    /// and the coil's lag where `lag`.
    CurrentLaw { reference_a: f64, lag: bool },
    /// θ = [`CURVE_NAMES`], with the anchor currents (A), and the coil's
    /// lag where `lag`.
    CurrentCurves { low_a: f64, high_a: f64, lag: bool },
}

impl ParameterModel {
    /// The model of `kind` for the damper law `law`; the curves' anchors
    /// (`anchors_a`) are known once the calibrated currents are (NaN until
    /// then). A current law has the coil's lag as a coordinate where `lag`
    /// (runs whose current varies). Only the B-P law follows the current
    /// ([`Self::check_law`] refuses the others in a current law).
    pub fn new(
        kind: ModelKind,
        law: LawKind,
        reference_a: f64,
        anchors_a: Option<(f64, f64)>,
        lag: bool,
    ) -> Self {
        match kind {
            ModelKind::PerCurrent if !law.is_bodner_partom() => ParameterModel::Law { law },
            ModelKind::PerCurrent => ParameterModel::PerCurrent,
            ModelKind::CurrentLaw => ParameterModel::CurrentLaw { reference_a, lag },
            ModelKind::CurrentCurves => {
                let (low_a, high_a) = anchors_a.unwrap_or((f64::NAN, f64::NAN));
                ParameterModel::CurrentCurves { low_a, high_a, lag }
            }
        }
    }

    /// Whether θ ends with the coil's lag.
    pub fn has_lag(&self) -> bool {
        matches!(
            self,
            ParameterModel::CurrentLaw { lag: true, .. }
                | ParameterModel::CurrentCurves { lag: true, .. }
        )
    }

    /// How the B-P parameters follow the coil current at θ (SI); `None`
    /// for one parameter set.
    pub fn field_law(&self, theta: &[f64]) -> Option<FieldLaw> {
        match *self {
            ParameterModel::PerCurrent | ParameterModel::Law { .. } => None,
            ParameterModel::CurrentLaw { reference_a, .. } => {
                Some(FieldLaw::Law(Self::current_law(reference_a, theta)))
            }
            ParameterModel::CurrentCurves { low_a, high_a, .. } => {
                Some(FieldLaw::Curves(Self::curves(low_a, high_a, theta)))
            }
        }
    }

    /// A law's field law and coil lag at θ (SI); `None` for one parameter
    /// set.
    pub fn field(&self, theta: &[f64]) -> Option<(FieldLaw, f64)> {
        self.field_law(theta).map(|law| (law, self.lag_s(theta)))
    }

    /// The coil's lag τ_c at θ (SI, s): 0 where θ has none.
    pub fn lag_s(&self, theta: &[f64]) -> f64 {
        if self.has_lag() {
            theta[self.names().len() - 1]
        } else {
            0.0
        }
    }

    /// Refuses a current law or current curves of a law other than B-P.
    pub fn check_law(kind: ModelKind, law: LawKind) -> Result<()> {
        if kind.is_law() && !law.is_bodner_partom() {
            return Err(Error::Usage(format!(
                "--model {} takes the B-P law; the {} law is calibrated per current (--model per-current)",
                clap::ValueEnum::to_possible_value(&kind).map(|v| v.get_name().to_string()).unwrap_or_default(),
                law.name()
            )));
        }
        Ok(())
    }

    /// Where θ's coordinates are walked above a floor (θ's position, the
    /// floor): every parameter of a law other than B-P, at the lower end
    /// of its physical range ([`super::Layout`] walks ln(θ − floor)), but
    /// the B-P element's of a law built around it ([`Self::has_bp_element`]);
    /// a parameter the law walks shifted (`DamperLaw::shifted`, c) has the
    /// floor −c, walked as ln(θ + c). The B-P law's models walk ln θ.
    pub fn floors(&self) -> Vec<(usize, f64)> {
        let skip = if self.has_bp_element() { crate::model::PARAM_NAMES.len() } else { 0 };
        match self {
            ParameterModel::Law { law } => {
                let law = law.law();
                let shift =
                    |i: usize| law.shifted().iter().find(|&&(j, _)| j == i).map(|&(_, c)| -c);
                law.parameters()
                    .iter()
                    .enumerate()
                    .map(|(i, p)| (i, shift(i).unwrap_or(p.range.0)))
                    .skip(skip)
                    .collect()
            }
            _ => Vec::new(),
        }
    }

    /// Whether θ holds the B-P law's own seven parameters, by their names
    /// and in their order: the B-P law, or a law built around its element
    /// (`bp-viscous`, `bp-spencer`), whose first seven parameters are the
    /// element's. Such a θ walks the B-P law's coordinates (ln θ, the
    /// stresses as the records fix them: [`super::Coordinates`]), not
    /// ln(θ − floor) for its B-P part: on the measured records the
    /// `bp-viscous` posterior's hardening lies along R0 + D1 ≈ const and
    /// m1 (R1 − R0) ≈ const (R0 with D1 −0.97, with R1 0.97), ridges that
    /// are straight in those coordinates and thin and curved in ln θ.
    pub fn has_bp_element(&self) -> bool {
        match self {
            ParameterModel::PerCurrent => true,
            ParameterModel::Law { law } => law
                .law()
                .parameters()
                .iter()
                .map(|p| p.name)
                .take(crate::model::PARAM_NAMES.len())
                .eq(crate::model::PARAM_NAMES),
            _ => false,
        }
    }

    /// The damper law whose parameters θ gives.
    pub fn law(&self) -> LawKind {
        match self {
            ParameterModel::Law { law } => *law,
            _ => LawKind::BodnerPartom,
        }
    }

    pub fn kind(&self) -> ModelKind {
        match self {
            ParameterModel::PerCurrent | ParameterModel::Law { .. } => ModelKind::PerCurrent,
            ParameterModel::CurrentLaw { .. } => ModelKind::CurrentLaw,
            ParameterModel::CurrentCurves { .. } => ModelKind::CurrentCurves,
        }
    }

    /// Whether θ describes several currents (a law or curves).
    pub fn is_current_law(&self) -> bool {
        self.kind().is_law()
    }

    /// Names of the θ coordinates, SI in outputs.
    pub fn names(&self) -> &'static [&'static str] {
        match self {
            ParameterModel::PerCurrent => &PARAM_NAMES,
            ParameterModel::Law { law } => law_names(*law),
            ParameterModel::CurrentLaw { lag: false, .. } => &LAW_NAMES,
            ParameterModel::CurrentLaw { lag: true, .. } => &LAW_NAMES_LAGGED,
            ParameterModel::CurrentCurves { lag: false, .. } => &CURVE_NAMES,
            ParameterModel::CurrentCurves { lag: true, .. } => &CURVE_NAMES_LAGGED,
        }
    }

    /// Where each (R1, D1) pair sits in θ: the saturated stress and its
    /// share, walked together in [`super::Coordinates::SaturationShare`].
    pub fn saturation_pairs(&self) -> Vec<(usize, usize)> {
        match self {
            ParameterModel::Law { .. } if !self.has_bp_element() => Vec::new(),
            ParameterModel::CurrentCurves { .. } => vec![
                (self.index("R1_low"), self.index("D1_low")),
                (self.index("R1_high"), self.index("D1_high")),
            ],
            _ => vec![(self.index("R1"), self.index("D1"))],
        }
    }

    /// The position of θ coordinate `name`; it must be one of [`Self::names`].
    pub fn index(&self, name: &str) -> usize {
        self.names().iter().position(|n| *n == name).expect("a coordinate of the parameter model")
    }

    /// Priors of θ from the priors of the law's parameters (`law`; the B-P
    /// law's seven for a current law or curves). In a current
    /// law those describe the reference current; G_field and G_zero each get
    /// G's prior, and I_s a log-normal with median I_ref and a factor e
    /// spread, within [0.05 I_ref, 20 I_ref]. The curves' values at each
    /// anchor get the parameter's prior, their bends [`BEND_PRIOR`].
    pub fn priors(&self, law: &[Prior]) -> Vec<Prior> {
        let mut p = law.to_vec();
        let bp = law;
        match *self {
            ParameterModel::PerCurrent | ParameterModel::Law { .. } => {}
            ParameterModel::CurrentLaw { reference_a, .. } => {
                p.push(Prior::LogNormal {
                    median: reference_a,
                    sd_log: 1.0,
                    lower: 0.05 * reference_a,
                    upper: 20.0 * reference_a,
                });
                p.push(bp[0]);
            }
            ParameterModel::CurrentCurves { .. } => {
                p.extend_from_slice(bp);
                p.extend([BEND_PRIOR; 7]);
            }
        }
        if self.has_lag() {
            p.push(LAG_PRIOR);
        }
        p
    }

    /// The current curves at θ (SI, in the order of [`CURVE_NAMES`]).
    pub fn curves(low_a: f64, high_a: f64, theta: &[f64]) -> CurrentCurves {
        CurrentCurves {
            low_a,
            high_a,
            low: Params::from_array(std::array::from_fn(|k| theta[k])),
            high: Params::from_array(std::array::from_fn(|k| theta[7 + k])),
            bend: std::array::from_fn(|k| theta[14 + k]),
        }
    }

    /// The current law at θ (SI, in the order of [`LAW_NAMES`]).
    fn current_law(reference_a: f64, theta: &[f64]) -> CurrentLaw {
        CurrentLaw {
            reference_a,
            g_field: theta[0],
            r0: theta[1],
            r1: theta[2],
            d1: theta[3],
            m1: theta[4],
            m2: theta[5],
            n: theta[6],
            saturation_a: theta[7],
            g_zero: theta[8],
        }
    }

    /// The law's parameters at a coil current from θ in SI units.
    pub fn values(&self, theta: &[f64], current_a: f64) -> LawValues {
        match *self {
            ParameterModel::Law { .. } => {
                let mut v = [0.0; crate::laws::MAX_LAW_PARAMETERS];
                let n = theta.len().min(v.len());
                v[..n].copy_from_slice(&theta[..n]);
                v
            }
            _ => values_of(&self.params(theta, current_a)),
        }
    }

    /// The B-P parameters at a coil current from θ in SI units (the B-P
    /// law's models; another law's θ gives nonsense here).
    pub fn params(&self, theta: &[f64], current_a: f64) -> Params {
        match *self {
            ParameterModel::PerCurrent | ParameterModel::Law { .. } => {
                Params::from_array(std::array::from_fn(|i| theta.get(i).copied().unwrap_or(0.0)))
            }
            ParameterModel::CurrentLaw { reference_a, .. } => {
                Self::current_law(reference_a, theta).params_at(current_a)
            }
            ParameterModel::CurrentCurves { low_a, high_a, .. } => {
                Self::curves(low_a, high_a, theta).params_at(current_a)
            }
        }
    }

    /// θ (SI) that gives `p` at `current_a`: the start of the MAP search
    /// from an identification. A current law starts with I_s = I_ref and
    /// half of G from the field; curves start flat (`p` at every current).
    pub fn start(&self, p: &Params, current_a: f64) -> Vec<f64> {
        let mut theta = self.start_without_lag(p, current_a);
        if self.has_lag() {
            // the prior's median
            theta.push(0.01);
        }
        theta
    }

    fn start_without_lag(&self, p: &Params, current_a: f64) -> Vec<f64> {
        let reference_a = match *self {
            ParameterModel::PerCurrent | ParameterModel::Law { .. } => {
                return p.to_array().to_vec()
            }
            ParameterModel::CurrentCurves { .. } => {
                let mut theta = p.to_array().to_vec();
                theta.extend(p.to_array());
                theta.extend([1.0; 7]);
                return theta;
            }
            ParameterModel::CurrentLaw { reference_a, .. } => reference_a,
        };
        let probe = CurrentLaw::through(p, reference_a, reference_a, 0.5);
        let s = probe.scale(current_a).max(1e-3);
        let clamp = |v: f64, i: usize| v.clamp(PHYSICAL_RANGE[i].0, PHYSICAL_RANGE[i].1);
        vec![
            clamp(0.5 * p.g / s, 0),
            clamp(p.r0 / s, 1),
            clamp(p.r1 / s, 2),
            clamp(p.d1 / s, 3),
            p.m1,
            p.m2,
            p.n,
            reference_a,
            0.5 * p.g,
        ]
    }

    /// The current whose runs the identification starts from: the one
    /// current of a per-current calibration, or the current nearest a
    /// law's reference. Refuses currents the model cannot take.
    pub fn identification_current(&self, currents: &[f64]) -> Result<f64> {
        match *self {
            ParameterModel::PerCurrent | ParameterModel::Law { .. } => match currents {
                [c] => Ok(*c),
                _ => Err(Error::Usage(format!(
                    "a calibration takes runs of one current; got {currents:?} A"
                ))),
            },
            ParameterModel::CurrentLaw { reference_a, .. }
            | ParameterModel::CurrentCurves { high_a: reference_a, .. } => {
                if currents.len() < 2 {
                    return Err(Error::Usage(format!(
                        "the current law needs runs at two or more currents; got {currents:?} A"
                    )));
                }
                Ok(currents
                    .iter()
                    .copied()
                    .min_by(|a, b| (a - reference_a).abs().total_cmp(&(b - reference_a).abs()))
                    .unwrap_or(reference_a))
            }
        }
    }

    /// The current the calibration's parameters describe: its one current,
    /// a law's reference, or the curves' high anchor.
    pub fn describes_current(&self, identification_current: f64) -> f64 {
        match *self {
            ParameterModel::PerCurrent | ParameterModel::Law { .. } => identification_current,
            ParameterModel::CurrentLaw { reference_a, .. } => reference_a,
            ParameterModel::CurrentCurves { high_a, .. } => high_a,
        }
    }
}

/// The names of a law's parameters, as a slice that lives as long as the
/// program (made once per law).
fn law_names(law: LawKind) -> &'static [&'static str] {
    static NAMES: std::sync::OnceLock<Vec<(LawKind, &'static [&'static str])>> =
        std::sync::OnceLock::new();
    let all = NAMES.get_or_init(|| {
        LawKind::ALL
            .iter()
            .map(|&k| {
                let names: &'static [&'static str] = Box::leak(k.law().names().into_boxed_slice());
                (k, names)
            })
            .collect()
    });
    all.iter().find(|(k, _)| *k == law).map(|(_, n)| *n).unwrap_or(&[])
}

/// A law's default priors: for each parameter a log-normal whose ±1 sd
/// spans its plausible values, truncated at its physical range (the B-P
/// law's rule, [`super::prior::default_priors`]).
pub fn law_priors(law: LawKind) -> Vec<Prior> {
    law.law().parameters().iter().map(|p| Prior::spanning(p.plausible, p.range)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The law's start at 1 A, with I_s = 1 A and G half from the field,
    /// reproduces the current dependence of the virtual stand.
    #[test]
    fn law_start_reproduces_the_virtual_stand() {
        let model = ParameterModel::CurrentLaw { reference_a: 1.0, lag: false };
        let stand = crate::synth::StandLaw::default().law();
        let theta = model.start(&Params::reference_1a(), 1.0);
        for i in [0.5, 1.0, 1.5] {
            let a = model.params(&theta, i).to_array();
            let b = stand.params_at(i).to_array();
            for k in 0..7 {
                assert!((a[k] / b[k] - 1.0).abs() < 1e-12, "{i} A, {k}: {} vs {}", a[k], b[k]);
            }
        }
        assert_eq!(model.names().len(), theta.len());
    }

    /// Curves map θ in the order of their names, start flat, and their
    /// priors line up with their names.
    #[test]
    fn curves_map_their_coordinates() {
        let model = ParameterModel::new(
            ModelKind::CurrentCurves,
            LawKind::BodnerPartom,
            1.0,
            Some((0.25, 1.0)),
            false,
        );
        let p = Params::reference_1a();
        let theta = model.start(&p, 0.5);
        assert_eq!(theta.len(), CURVE_NAMES.len());
        let close = |a: f64, b: f64| (a / b - 1.0).abs() < 1e-13;
        for (a, b) in model.params(&theta, 0.1).to_array().iter().zip(p.to_array()) {
            assert!(close(*a, b), "flat curves: {a} vs {b}");
        }
        let priors = model.priors(&crate::posterior::prior::default_priors());
        assert_eq!(priors.len(), CURVE_NAMES.len());
        assert_eq!(priors[model.index("n_high")], priors[6]);
        assert_eq!(priors[model.index("G_bend")], BEND_PRIOR);
        // BEND_PRIOR's bounds are e^∓6
        let (lo, hi) = BEND_PRIOR.bounds();
        assert!((lo.ln() + 6.0).abs() < 1e-12 && (hi.ln() - 6.0).abs() < 1e-12);
        let mut t = theta.clone();
        t[model.index("D1_high")] *= 2.0;
        assert!(close(model.params(&t, 1.0).d1, 2.0 * p.d1));
        assert!(close(model.params(&t, 0.25).d1, p.d1));
        assert_eq!(model.describes_current(0.5), 1.0);
    }
}
