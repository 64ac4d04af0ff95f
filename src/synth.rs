//! Virtual experiments: stand records produced by a damper law (the B-P
//! model unless another is named).
//!
//! The stand drives the damper by a crank-slider from rest; the model is
//! integrated along the exact displacement with a fine step, and sensor noise
//! is added to force and displacement. The bundled campaign in `data/` is
//! made this way ([`SynthSettings::default`]); `mrbp synth --out data`
//! regenerates it bit for bit.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::Path;

use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::atomic;
use crate::data::{Columns, Geometry, Manifest, Record, RunSpec};
use crate::error::{Error, Result};
use crate::laws::{LawKind, LawValues};
use crate::model::{CurrentCurves, CurrentLaw, FieldLaw, Integrator, Params, LANES};
use crate::noise::Kernel;
use crate::plot::{self, Chart, Figure, LegendAt, Series, PALETTE};

/// Crank-slider kinematics of the test stand.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Crank {
    /// Crank radius r (m): the stroke is 2r.
    pub radius_m: f64,
    /// Connecting-rod length L (m).
    pub rod_m: f64,
}

impl Default for Crank {
    /// r = 6.75 mm gives the paper's nominal shear rates (mean |γ̇| = 4 r f / h
    /// = 45, 90, 180 1/s at 100, 200, 400 rpm with h = 1 mm).
    fn default() -> Self {
        Crank { radius_m: 6.75e-3, rod_m: 0.15 }
    }
}

impl Crank {
    /// Piston displacement (m) at time `t` with the crank at `rpm`, starting
    /// from bottom dead centre (x = 0, at rest):
    /// x = r(1 − cos θ) + L − √(L² − r² sin² θ), θ = 2π rpm t / 60.
    pub fn displacement(&self, rpm: f64, t: f64) -> f64 {
        let theta = 2.0 * PI * rpm / 60.0 * t;
        let (r, l) = (self.radius_m, self.rod_m);
        r * (1.0 - theta.cos()) + l - (l * l - (r * theta.sin()).powi(2)).sqrt()
    }

    /// Piston velocity (m/s) at time `t`, the derivative of
    /// [`Self::displacement`]: ẋ = ω r sin θ (1 + r cos θ / √(L² − r² sin² θ)).
    pub fn velocity(&self, rpm: f64, t: f64) -> f64 {
        let omega = 2.0 * PI * rpm / 60.0;
        let (sin, cos) = (omega * t).sin_cos();
        let (r, l) = (self.radius_m, self.rod_m);
        omega * r * sin * (1.0 + r * cos / (l * l - (r * sin).powi(2)).sqrt())
    }

    /// Mean |γ̇| over a cycle (1/s): the nominal shear rate of the paper.
    pub fn nominal_shear_rate(&self, rpm: f64, gap_m: f64) -> f64 {
        4.0 * self.radius_m * rpm / 60.0 / gap_m
    }
}

/// The virtual stand's fluid: its B-P parameters at 1 A and how they follow
/// the coil current, as the settings file writes them.
///
/// The stand uses the current law of [`crate::model::CurrentLaw`] with
/// reference current 1 A and saturation current `saturation_a`; the
/// pre-yield modulus G is half field-induced, half the carrier fluid's, so
/// G(I) = G (1 + s(I))/2, and m1, m2, n do not depend on the field. With
/// `[law.curves]` it follows those curves instead ([`CurrentCurves`]:
/// an off-state, each parameter its own bend, G may fall), and `at_1a` and
/// `saturation_a` are not used.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StandLaw {
    pub at_1a: Params,
    /// Saturation current I_s (A).
    pub saturation_a: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub curves: Option<CurrentCurves>,
    /// The coil's lag τ_c (s): how far the field trails a current that
    /// changes ([`crate::model::FieldCurrent`]; the switched records').
    #[serde(default = "default_lag", skip_serializing_if = "is_default_lag")]
    pub coil_lag_s: f64,
}

/// The stand coil's lag unless `synth.toml` says otherwise (s).
const DEFAULT_LAG_S: f64 = 0.01;

fn default_lag() -> f64 {
    DEFAULT_LAG_S
}

fn is_default_lag(v: &f64) -> bool {
    *v == DEFAULT_LAG_S
}

impl Default for StandLaw {
    fn default() -> Self {
        StandLaw {
            at_1a: Params::reference_1a(),
            saturation_a: 1.0,
            curves: None,
            coil_lag_s: DEFAULT_LAG_S,
        }
    }
}

impl StandLaw {
    pub fn law(&self) -> CurrentLaw {
        CurrentLaw::through(&self.at_1a, 1.0, self.saturation_a, 0.5)
    }

    /// How the stand's parameters follow the current.
    pub fn field_law(&self) -> FieldLaw {
        match &self.curves {
            Some(c) => FieldLaw::Curves(*c),
            None => FieldLaw::Law(self.law()),
        }
    }

    /// The fluid's B-P parameters at `current_a`.
    pub fn params_at(&self, current_a: f64) -> Params {
        match &self.curves {
            Some(c) => c.params_at(current_a),
            None => self.law().params_at(current_a),
        }
    }
}

/// Everything that defines a virtual campaign.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SynthSettings {
    pub name: String,
    pub geometry: Geometry,
    pub crank: Crank,
    pub law: StandLaw,
    pub currents_a: Vec<f64>,
    pub rpms: Vec<f64>,
    /// Crank revolutions recorded per run.
    pub cycles: f64,
    /// Sampling rate (Hz).
    pub rate_hz: f64,
    /// Standard deviation of the force sensor noise (N).
    pub noise_force_n: f64,
    /// Standard deviation of the displacement sensor noise (m).
    pub noise_displacement_m: f64,
    pub seed: u64,
    /// A force the B-P law does not carry, added to every record (none by
    /// default): to see what a calibration makes of a law that is not the
    /// whole truth.
    #[serde(default, skip_serializing_if = "ExtraForce::is_none")]
    pub extra_force: ExtraForce,
    /// Records whose current is switched while the crank turns
    /// (`[[switched]]`), beside the records of one current each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub switched: Vec<SwitchedRun>,
    /// Another damper law than the B-P fluid of `[law]` (`[damper]`,
    /// `mrbp synth --law NAME`): the records are that law's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damper: Option<Damper>,
}

/// The stand's damper as a law other than the B-P fluid: its parameters
/// at 1 A by name (SI; a parameter not named takes the law's typical
/// value, [`crate::laws::DamperLaw::typical`]). Its forces (N) and
/// dashpots (N s/m) follow the coil current as the stand's stresses do,
/// by s(I)/s(1 A) with s(I) = tanh(I/I_s) and `[law] saturation_a` = I_s;
/// its other parameters do not.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Damper {
    pub law: LawKind,
    #[serde(default)]
    pub at_1a: BTreeMap<String, f64>,
}

impl Damper {
    /// The law with its typical parameters at 1 A.
    pub fn typical(law: LawKind) -> Damper {
        let l = law.law();
        let values = l.typical();
        Damper {
            law,
            at_1a: l.names().iter().zip(values).map(|(n, v)| (n.to_string(), v)).collect(),
        }
    }

    /// The damper of law `law` whose parameters at `current_a` are
    /// `values` (in the order of the law's parameters), with the stand's
    /// saturation current `saturation_a`: the inverse of
    /// [`Damper::values_at`].
    pub fn through(law: LawKind, values: &[f64], current_a: f64, saturation_a: f64) -> Damper {
        let scale = current_scale(current_a, saturation_a);
        let at_1a = law
            .law()
            .parameters()
            .iter()
            .zip(values)
            .map(|(p, v)| (p.name.to_string(), if follows_current(p) { v / scale } else { *v }))
            .collect();
        Damper { law, at_1a }
    }

    /// The parameters at `current_a` with the stand's saturation current
    /// `saturation_a`; refuses a name the law does not have.
    pub fn values_at(&self, current_a: f64, saturation_a: f64) -> Result<LawValues> {
        let law = self.law.law();
        let names = law.names();
        if let Some(unknown) = self.at_1a.keys().find(|k| !names.contains(&k.as_str())) {
            return Err(Error::Usage(format!(
                "[damper.at_1a]: the {} law has no parameter '{unknown}' (its are {})",
                self.law.name(),
                names.join(", ")
            )));
        }
        let scale = current_scale(current_a, saturation_a);
        let mut values = law.typical();
        for (k, p) in law.parameters().iter().enumerate() {
            let at_1a = self.at_1a.get(p.name).copied().unwrap_or(values[k]);
            values[k] = if follows_current(p) { at_1a * scale } else { at_1a };
        }
        law.validate(&values)
            .map_err(|e| Error::Usage(format!("[damper] at {current_a} A: {e}")))?;
        Ok(values)
    }
}

/// s(I)/s(1 A) with s(I) = tanh(I/I_s): how a damper's forces and
/// dashpots follow the coil current on the stand.
fn current_scale(current_a: f64, saturation_a: f64) -> f64 {
    (current_a / saturation_a).tanh() / (1.0 / saturation_a).tanh()
}

/// Whether a damper law's parameter follows the coil current on the stand
/// (its forces and dashpots do; its shapes and stiffness ratios do not).
fn follows_current(p: &crate::laws::LawParameter) -> bool {
    p.unit == "N" || p.unit == "N s/m"
}

/// A record whose coil current steps through `levels_a`, round and round,
/// each level held for its entry of `holds_s` (one value: every level
/// alike): a step programme (levels 0.25, 1.0, 0.5 A, 80 ms each) or a
/// PWM-like command (levels 0 and 1 A, held 6 and 14 ms: 50 Hz at 70 %).
/// The record's current column is the command; the field trails it by the
/// stand's coil lag.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SwitchedRun {
    pub rpm: f64,
    pub levels_a: Vec<f64>,
    pub holds_s: Vec<f64>,
}

impl SwitchedRun {
    /// Checks the programme; `law` must hold at every level.
    fn check(&self, law: &StandLaw) -> Result<()> {
        let bad = |m: String| Err(Error::Usage(format!("[[switched]] at {} rpm: {m}", self.rpm)));
        if !(self.rpm > 0.0) || self.levels_a.len() < 2 {
            return bad("needs a positive rpm and two or more levels_a".into());
        }
        if !(self.holds_s.len() == 1 || self.holds_s.len() == self.levels_a.len())
            || self.holds_s.iter().any(|h| !(*h > 0.0 && h.is_finite()))
        {
            return bad(format!(
                "holds_s must be one positive time or one per level ({} levels)",
                self.levels_a.len()
            ));
        }
        for &level in &self.levels_a {
            if !(level >= 0.0 && level.is_finite()) {
                return bad(format!("level {level} A: a coil current is 0 A or more"));
            }
            if let Err(e) = law.params_at(level).validate() {
                return bad(format!("at {level} A the stand's law has {e} (the tanh law has no yield stress at 0 A: use [law.curves])"));
            }
        }
        if !(law.coil_lag_s >= 0.0 && law.coil_lag_s.is_finite()) {
            return bad(format!("coil_lag_s = {} must be 0 or positive", law.coil_lag_s));
        }
        Ok(())
    }

    /// The commanded current at time `t`.
    pub fn current_at(&self, t: f64) -> f64 {
        let hold =
            |i: usize| if self.holds_s.len() == 1 { self.holds_s[0] } else { self.holds_s[i] };
        let cycle: f64 = (0..self.levels_a.len()).map(hold).sum();
        let mut into = t.rem_euclid(cycle);
        for (i, level) in self.levels_a.iter().enumerate() {
            if into < hold(i) {
                return *level;
            }
            into -= hold(i);
        }
        self.levels_a[self.levels_a.len() - 1]
    }

    /// The run's id: `S<k>_<rpm>rpm` for the k-th switched record (from 1).
    pub fn id(&self, k: usize) -> String {
        format!("S{k}_{:.0}rpm", self.rpm)
    }
}

/// The virtual stand's force beyond the B-P law (`[extra_force]`): a
/// smooth random force — a path of the discrepancy model's own process
/// (`--noise discrepancy`), so its scale and time scale are known truths —
/// and a velocity-proportional force, which no noise model of mrbp has.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ExtraForce {
    /// Standard deviation of the smooth force (N): one value for every run,
    /// or one per crank speed (in the order of `rpms`); empty or 0: none.
    pub smooth_sd_n: Vec<f64>,
    /// Its time scale ℓ (s), as `smooth_sd_n`: the Matérn kernel's, as the
    /// discrepancy model defines it.
    pub smooth_time_s: Vec<f64>,
    /// Its kernel.
    pub kernel: Kernel,
    /// A viscous force c ẋ (N s/m) on the exact piston velocity.
    pub viscous_n_s_per_m: f64,
}

impl ExtraForce {
    fn is_none(&self) -> bool {
        self.smooth_sd_n.iter().all(|s| *s == 0.0) && self.viscous_n_s_per_m == 0.0
    }

    /// The smooth force's (scale (N), time scale (s)) on the run at crank
    /// speed number `i` of `n`; None where it has none.
    pub fn smooth(&self, i: usize, n: usize) -> Result<Option<(f64, f64)>> {
        let pick = |v: &[f64], what: &str| -> Result<f64> {
            match v.len() {
                1 => Ok(v[0]),
                len if len == n => Ok(v[i]),
                len => Err(Error::Usage(format!("extra force: {what} has {len} values for {n} crank speeds (give one, or one per speed)"))),
            }
        };
        if self.smooth_sd_n.is_empty() {
            return Ok(None);
        }
        let sd = pick(&self.smooth_sd_n, "smooth_sd_n")?;
        if sd == 0.0 {
            return Ok(None);
        }
        if self.smooth_time_s.is_empty() {
            return Err(Error::Usage("extra force: a smooth force needs its time scale (smooth_time_s, --smooth-force-time)".into()));
        }
        let ell = pick(&self.smooth_time_s, "smooth_time_s")?;
        if !(sd > 0.0 && sd.is_finite() && ell > 0.0 && ell.is_finite()) {
            return Err(Error::Usage(format!("extra force: the smooth force's scale ({sd} N) and time scale ({ell} s) must be positive")));
        }
        Ok(Some((sd, ell)))
    }
}

impl Default for SynthSettings {
    fn default() -> Self {
        SynthSettings {
            name: "rd1005-3-virtual".into(),
            geometry: Geometry { area_m2: 0.05, gap_m: 1.0e-3 },
            crank: Crank::default(),
            law: StandLaw::default(),
            currents_a: vec![0.5, 1.0, 1.5],
            rpms: vec![100.0, 200.0, 400.0],
            cycles: 2.0,
            rate_hz: 5000.0,
            noise_force_n: 15.0,
            noise_displacement_m: 2.0e-6,
            seed: 20_261_122,
            extra_force: ExtraForce::default(),
            switched: Vec::new(),
            damper: None,
        }
    }
}

impl SynthSettings {
    /// Reads a settings file (the `synth.toml` format).
    pub fn read(path: &Path) -> Result<SynthSettings> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
        toml::from_str(&text)
            .map_err(|e| Error::input(path, format!("invalid synth settings: {}", e.message())))
    }

    /// Writes the settings file `synth.toml` into `dir`.
    fn write(&self, dir: &Path) -> Result<()> {
        let text = toml::to_string(self).map_err(|e| Error::Compute(e.to_string()))?;
        atomic::write(
            &dir.join("synth.toml"),
            format!("# Settings of `mrbp synth` that made this campaign.\n{text}").as_bytes(),
        )
    }
}

/// The options that override a virtual stand's settings (`mrbp synth`,
/// `mrbp study plan`).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct Overrides {
    /// Coil currents (A), comma separated
    #[arg(long, value_delimiter = ',')]
    pub currents: Option<Vec<f64>>,
    /// Crank speeds (rpm), comma separated
    #[arg(long, value_delimiter = ',')]
    pub rpm: Option<Vec<f64>>,
    /// Crank revolutions per record
    #[arg(long)]
    pub cycles: Option<f64>,
    /// Sampling rate (Hz)
    #[arg(long)]
    pub rate: Option<f64>,
    /// Force sensor noise, standard deviation (N)
    #[arg(long)]
    pub noise_force: Option<f64>,
    /// Displacement sensor noise, standard deviation (m)
    #[arg(long)]
    pub noise_displacement: Option<f64>,
    /// A smooth force the law lacks: its standard deviation (N), one value
    /// or one per crank speed (a path of the discrepancy model's process)
    #[arg(long, value_delimiter = ',', value_name = "N")]
    pub smooth_force: Option<Vec<f64>>,
    /// The smooth force's time scale (s), one value or one per crank speed
    #[arg(long, value_delimiter = ',', value_name = "SECONDS")]
    pub smooth_force_time: Option<Vec<f64>>,
    /// A viscous force the law lacks, c times the piston velocity (N s/m)
    #[arg(long, value_name = "N_S_PER_M")]
    pub viscous_force: Option<f64>,
    /// The damper law the records are made with (default: the B-P fluid of
    /// the settings' `[law]`; another law with its typical parameters at 1 A
    /// unless the settings' `[damper]` names them). In `study plan`, the
    /// law of the calibrations' `--law`.
    #[arg(skip)]
    pub law: Option<LawKind>,
}

impl Overrides {
    /// The settings file `config` (or the bundled campaign's settings) with
    /// these overrides applied, and the sensor noise's `seed` if given.
    pub fn settings(&self, config: Option<&Path>, seed: Option<u64>) -> Result<SynthSettings> {
        let mut s = match config {
            Some(path) => SynthSettings::read(path)?,
            None => SynthSettings::default(),
        };
        if let Some(v) = &self.currents {
            s.currents_a = v.clone();
        }
        if let Some(v) = &self.rpm {
            s.rpms = v.clone();
        }
        s.cycles = self.cycles.unwrap_or(s.cycles);
        s.rate_hz = self.rate.unwrap_or(s.rate_hz);
        s.noise_force_n = self.noise_force.unwrap_or(s.noise_force_n);
        s.noise_displacement_m = self.noise_displacement.unwrap_or(s.noise_displacement_m);
        s.seed = seed.unwrap_or(s.seed);
        if let Some(v) = &self.smooth_force {
            s.extra_force.smooth_sd_n = v.clone();
        }
        if let Some(v) = &self.smooth_force_time {
            s.extra_force.smooth_time_s = v.clone();
        }
        s.extra_force.viscous_n_s_per_m =
            self.viscous_force.unwrap_or(s.extra_force.viscous_n_s_per_m);
        match self.law {
            None => {}
            Some(LawKind::BodnerPartom) => s.damper = None,
            Some(law) if s.damper.as_ref().is_some_and(|d| d.law == law) => {}
            Some(law) => s.damper = Some(Damper::typical(law)),
        }
        Ok(s)
    }
}

/// Sub-steps per sample for the "true" response, with Richardson
/// extrapolation (second order): the discretisation error is then below
/// 0.01 Pa, far below the sensor noise and below what a narrow posterior
/// could notice.
const TRUTH_SUBSTEPS: u32 = 16;

/// The random stream of a record's extra force, beside its sensor noise's.
const EXTRA_FORCE_STREAM: u64 = 0xe7f;

/// What a virtual record's true stress comes from: the stand's B-P fluid
/// or another damper law, at the record's current.
#[derive(Clone, Copy, Debug)]
pub enum Truth {
    BodnerPartom(Params),
    Law(LawKind, LawValues),
}

/// One virtual record: `cycles` crank revolutions at `rpm` of the damper
/// `truth`, noise from the stream `(seed, stream)`, and the extra force
/// with the smooth force `smooth` (scale (N), time scale (s)).
pub fn virtual_record(
    settings: &SynthSettings,
    truth: &Truth,
    rpm: f64,
    current_a: f64,
    smooth: Option<(f64, f64)>,
    stream: u64,
) -> Result<Record> {
    let n = intervals(settings, rpm) as usize;
    let time: Vec<f64> = (0..=n).map(|k| k as f64 / settings.rate_hz).collect();
    let x: Vec<f64> = time.iter().map(|&t| settings.crank.displacement(rpm, t)).collect();
    let gamma: Vec<f64> = x.iter().map(|x| x / settings.geometry.gap_m).collect();
    let integrator = Integrator {
        substeps: TRUTH_SUBSTEPS,
        extrapolate: true,
        max_substeps: 1_000_000,
        ..Integrator::default()
    };
    let failed = |e| Error::Compute(format!("virtual experiment at {rpm} rpm: {e}"));
    let tau = match truth {
        Truth::BodnerPartom(p) => integrator.run(p, &time, &gamma).map_err(failed)?.tau,
        Truth::Law(law, values) => {
            let g = settings.geometry;
            let run = crate::data::RunData::new(
                String::new(),
                time.clone(),
                gamma,
                vec![0.0; n + 1],
                0.0,
                current_a,
                (g.area_m2, g.gap_m),
                (0.0, 0.0),
            );
            law.law().path(&integrator, values, &run).map_err(failed)?
        }
    };
    sensed(settings, rpm, time, x, &tau, vec![current_a; n + 1], smooth, stream)
}

/// Finer time steps per sample of a switched record's true response: the
/// field, and with it the parameters, changes within a sample interval.
const SWITCHED_OVERSAMPLING: usize = 8;

/// One switched-current record (`[[switched]]`): the command held from
/// sample to sample, the field trailing it by the coil's lag, the truth
/// integrated on a grid 8× finer than the samples (with the command held
/// over each sample interval) so that it does not share the likelihood's
/// discretisation; sensor noise from the stream `(seed, stream)`.
pub fn switched_record(settings: &SynthSettings, run: &SwitchedRun, stream: u64) -> Result<Record> {
    let rpm = run.rpm;
    let n = intervals(settings, rpm) as usize;
    let time: Vec<f64> = (0..=n).map(|k| k as f64 / settings.rate_hz).collect();
    let x: Vec<f64> = time.iter().map(|&t| settings.crank.displacement(rpm, t)).collect();
    let current: Vec<f64> = time.iter().map(|&t| run.current_at(t)).collect();
    let m = SWITCHED_OVERSAMPLING;
    let fine_t: Vec<f64> = (0..=n * m).map(|k| k as f64 / (settings.rate_hz * m as f64)).collect();
    let fine_gamma: Vec<f64> = fine_t
        .iter()
        .map(|&t| settings.crank.displacement(rpm, t) / settings.geometry.gap_m)
        .collect();
    let fine_current: Vec<f64> = (0..=n * m).map(|k| current[k / m]).collect();
    let lanes = [settings.law.field_law(); LANES];
    let mut fine_tau = vec![0.0; fine_t.len()];
    let integrator = Integrator {
        substeps: TRUTH_SUBSTEPS / m as u32,
        extrapolate: true,
        max_substeps: 1_000_000,
        ..Integrator::default()
    };
    let [outcome, ..] = integrator.run_lanes_along(
        &lanes,
        &[settings.law.coil_lag_s; LANES],
        &fine_current,
        &fine_t,
        &fine_gamma,
        0.0,
        |k, s| fine_tau[k] = s.tau[0],
    );
    outcome
        .map_err(|e| Error::Compute(format!("switched virtual experiment at {rpm} rpm: {e}")))?;
    let tau: Vec<f64> = (0..=n).map(|k| fine_tau[k * m]).collect();
    sensed(settings, rpm, time, x, &tau, current, None, stream)
}

/// The record the stand's sensors give of the true stress `tau` along the
/// piston displacement `x` at the sample `time`s: force and displacement
/// noise from the stream `(seed, stream)`, the extra force (the smooth
/// one `smooth`) added, and the coil current `current`.
#[allow(clippy::too_many_arguments)]
fn sensed(
    settings: &SynthSettings,
    rpm: f64,
    time: Vec<f64>,
    x: Vec<f64>,
    tau: &[f64],
    current: Vec<f64>,
    smooth: Option<(f64, f64)>,
    stream: u64,
) -> Result<Record> {
    let mut rng = crate::rng::stream(settings.seed, &[stream]);
    let noise =
        |sd: f64| Normal::new(0.0, sd).map_err(|e| Error::Usage(format!("noise level {sd}: {e}")));
    let force_noise = noise(settings.noise_force_n)?;
    let disp_noise = noise(settings.noise_displacement_m)?;
    let mut force = Vec::with_capacity(time.len());
    let mut displacement = Vec::with_capacity(time.len());
    for (tau, x) in tau.iter().zip(&x) {
        force.push(tau * settings.geometry.area_m2 + force_noise.sample(&mut rng));
        displacement.push(x + disp_noise.sample(&mut rng));
    }
    // the extra force from a stream of its own: records without it are
    // those of earlier versions, bit for bit
    if let Some((sd, ell)) = smooth {
        let mut rng = crate::rng::stream(settings.seed, &[stream, EXTRA_FORCE_STREAM]);
        let path = crate::noise::discrepancy::sample_path(
            settings.extra_force.kernel, sd, ell, &time, &mut rng,
        );
        force.iter_mut().zip(path).for_each(|(f, d)| *f += d);
    }
    let c = settings.extra_force.viscous_n_s_per_m;
    if c != 0.0 {
        force.iter_mut().zip(&time).for_each(|(f, &t)| *f += c * settings.crank.velocity(rpm, t));
    }
    Ok(Record { current: Some(current), time, displacement, force })
}

/// Fewest samples a revolution of the crank: each of its four quarter
/// strokes (a loading and an unloading each way) gets two, or the record
/// does not trace a loop (at fewer than two a revolution it aliases to
/// another motion altogether).
const SAMPLES_PER_REVOLUTION: f64 = 8.0;

/// Most samples a record: a 1 kHz record of 2 h 47 min, 400 MB of the
/// truth's integration and the CSV; beyond it `--rate` or `--cycles` is
/// surely a slip.
const MAX_SAMPLES: f64 = 1e7;

/// How many sampling intervals a record at `rpm` spans: its `cycles`
/// revolutions at the settings' rate (the record has one sample more).
fn intervals(settings: &SynthSettings, rpm: f64) -> f64 {
    let duration = settings.cycles * 60.0 / rpm;
    (duration * settings.rate_hz).round()
}

/// Whether every record of `settings` (each crank speed, each switched
/// run) is sampled as [`sampled_enough`] asks: what `synth` and a virtual
/// study's plan check before anything is written.
pub fn check_sampling(settings: &SynthSettings) -> Result<()> {
    let switched = settings.switched.iter().map(|r| &r.rpm);
    settings.rpms.iter().chain(switched).try_for_each(|rpm| sampled_enough(settings, *rpm))
}

/// Whether a record at `rpm` with the settings' rate and revolutions is one
/// loading can read and the law can be calibrated on: at least
/// [`crate::data::table::MIN_ROWS`] samples (what loading refuses below),
/// [`SAMPLES_PER_REVOLUTION`] a revolution, and at most [`MAX_SAMPLES`].
fn sampled_enough(settings: &SynthSettings, rpm: f64) -> Result<()> {
    let (rate, cycles) = (settings.rate_hz, settings.cycles);
    let per_revolution = rate * 60.0 / rpm;
    let samples = intervals(settings, rpm) + 1.0;
    let at = format!("at {rpm} rpm, {cycles} revolution(s) sampled at {rate} Hz");
    let min_rows = crate::data::table::MIN_ROWS as f64;
    if !(per_revolution >= SAMPLES_PER_REVOLUTION) {
        let shown = match per_revolution >= 0.01 {
            true => format!("{per_revolution:.3}"),
            false => format!("{per_revolution:.1e}"),
        };
        return Err(Error::Usage(format!(
            "{at} give {shown} samples a revolution; a record needs at least {SAMPLES_PER_REVOLUTION} to trace the loop: raise --rate to {} Hz or more",
            (SAMPLES_PER_REVOLUTION * rpm / 60.0).ceil()
        )));
    }
    if !(samples >= min_rows) {
        return Err(Error::Usage(format!(
            "{at} give {samples} samples; a record needs at least {min_rows}: raise --cycles or --rate"
        )));
    }
    if !(samples <= MAX_SAMPLES) {
        return Err(Error::Usage(format!(
            "{at} give {samples:.3e} samples, more than the {MAX_SAMPLES:.0e} a virtual record may have: lower --cycles or --rate"
        )));
    }
    Ok(())
}

/// Run id used in the manifest, e.g. `I1.0_100rpm`.
pub fn run_id(current_a: f64, rpm: f64) -> String {
    format!("I{current_a:.1}_{rpm:.0}rpm")
}

/// Writes a whole virtual campaign into `dir`: the manifest, one CSV per
/// run, the settings used (`synth.toml`) and a figure of the force-
/// displacement loops (`records.svg`, `records.png`).
pub fn write_campaign(settings: &SynthSettings, dir: &Path) -> Result<Manifest> {
    if settings.rate_hz <= 0.0 || settings.cycles <= 0.0 || settings.rpms.iter().any(|r| *r <= 0.0)
    {
        return Err(Error::Usage("rate, cycles and rpm must be positive".into()));
    }
    if let Some(bad) = settings.currents_a.iter().find(|c| !(c.is_finite() && **c >= 0.0)) {
        return Err(Error::Usage(format!("coil currents must be 0 A or more; got {bad} A")));
    }
    check_sampling(settings)?;
    if settings.currents_a.is_empty() {
        return Err(Error::Usage("no coil current to make records at".into()));
    }
    for i in 0..settings.rpms.len() {
        settings.extra_force.smooth(i, settings.rpms.len())?;
    }
    if !settings.extra_force.viscous_n_s_per_m.is_finite() {
        return Err(Error::Usage("extra force: the viscous coefficient must be finite".into()));
    }
    if let Some(c) = &settings.law.curves {
        if !(c.low_a >= 0.0 && c.high_a > c.low_a && c.high_a.is_finite()) {
            return Err(Error::Usage(format!(
                "[law.curves]: need anchor currents 0 ≤ low_a < high_a; got {} and {}",
                c.low_a, c.high_a
            )));
        }
        if let Some(k) = c.bend.iter().position(|b| !(*b > 0.0 && b.is_finite())) {
            return Err(Error::Usage(format!(
                "[law.curves]: bend {} of {} must be positive and finite",
                c.bend[k],
                crate::model::PARAM_NAMES[k]
            )));
        }
    }
    for run in &settings.switched {
        run.check(&settings.law)?;
    }
    if let (Some(d), false) = (&settings.damper, settings.switched.is_empty()) {
        return Err(Error::Usage(format!(
            "switched-current records follow the B-P fluid's current law; the {} law of [damper] has none",
            d.law.name()
        )));
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    let _held = crate::lock::write(dir)?;
    crate::atomic::clean_leftovers(dir)?;
    // the manifest says the campaign is whole: it goes first, comes back last
    crate::atomic::remove(&dir.join("campaign.toml"))?;
    let mut runs = Vec::new();
    let mut panels = Vec::new();
    let mut stream = 0u64;
    for &current in &settings.currents_a {
        let truth = match &settings.damper {
            Some(d) => Truth::Law(d.law, d.values_at(current, settings.law.saturation_a)?),
            None => {
                let p = settings.law.params_at(current);
                p.validate().map_err(|e| Error::Usage(format!("at {current} A: {e}")))?;
                Truth::BodnerPartom(p)
            }
        };
        let mut chart = Chart::new(
            format!("virtual records at {current} A"),
            "piston displacement x (mm)",
            "damper force F (kN)",
        );
        chart.legend_at = LegendAt::Middle;
        for (i, &rpm) in settings.rpms.iter().enumerate() {
            let id = run_id(current, rpm);
            let file = format!("{id}.csv");
            let smooth = settings.extra_force.smooth(i, settings.rpms.len())?;
            let rec = virtual_record(settings, &truth, rpm, current, smooth, stream)?;
            stream += 1;
            chart.series.push(
                Series::line(
                    Some(format!("{rpm} rpm")),
                    PALETTE[i % PALETTE.len()],
                    rec.displacement.iter().map(|x| x * 1e3).collect(),
                    rec.force.iter().map(|f| f * 1e-3).collect(),
                )
                .with_width(1),
            );
            atomic::write(&dir.join(&file), crate::data::table::csv_text(&rec).as_bytes())?;
            runs.push(RunSpec {
                id,
                file: file.into(),
                current_a: current,
                shear_rate: Some(
                    (settings.crank.nominal_shear_rate(rpm, settings.geometry.gap_m) * 10.0)
                        .round()
                        / 10.0,
                ),
                initial_stress_pa: None,
                current_varies: false,
            });
        }
        panels.push(chart);
    }
    if !settings.switched.is_empty() {
        let mut chart = Chart::new(
            "switched-current records", "piston displacement x (mm)", "damper force F (kN)",
        );
        chart.legend_at = LegendAt::Middle;
        for (k, run) in settings.switched.iter().enumerate() {
            let id = run.id(k + 1);
            let file = format!("{id}.csv");
            let rec = switched_record(settings, run, stream)?;
            stream += 1;
            chart.series.push(
                Series::line(
                    Some(id.clone()),
                    PALETTE[k % PALETTE.len()],
                    rec.displacement.iter().map(|x| x * 1e3).collect(),
                    rec.force.iter().map(|f| f * 1e-3).collect(),
                )
                .with_width(1),
            );
            // the run's nominal current: the command's mean over the record
            let current = rec.current.as_deref().unwrap_or(&[]);
            let mean = current.iter().sum::<f64>() / current.len().max(1) as f64;
            atomic::write(&dir.join(&file), crate::data::table::csv_text(&rec).as_bytes())?;
            runs.push(RunSpec {
                id,
                file: file.into(),
                current_a: (mean * 1e3).round() / 1e3,
                shear_rate: Some(
                    (settings.crank.nominal_shear_rate(run.rpm, settings.geometry.gap_m) * 10.0)
                        .round()
                        / 10.0,
                ),
                initial_stress_pa: None,
                current_varies: true,
            });
        }
        panels.push(chart);
    }
    plot::save(&Figure::grid(panels, 3), &dir.join("records"))?;
    let manifest = Manifest {
        name: settings.name.clone(),
        geometry: settings.geometry,
        columns: Columns::default(),
        limits: Default::default(),
        runs,
    };
    let extra = if settings.extra_force.is_none() {
        ""
    } else {
        " + a force the law lacks ([extra_force])"
    };
    // the law the records were made with ([damper], else the B-P fluid)
    let law = match &settings.damper {
        Some(d) if !d.law.is_bodner_partom() => format!("the {} law", d.law.name()),
        _ => "B-P model".to_string(),
    };
    let header = format!(
        "# Virtual test campaign made by `mrbp synth` (see synth.toml beside it).\n\
         # Synthetic data: {law}{extra} + sensor noise, not measurements.\n"
    );
    settings.write(dir)?;
    manifest.write(&dir.join("campaign.toml"), &header)?;
    Ok(manifest)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crank_starts_at_rest_and_strokes_2r() {
        let c = Crank::default();
        assert_eq!(c.displacement(100.0, 0.0), 0.0);
        // velocity at t = 0 is zero: displacement is second order in t
        let x1 = c.displacement(100.0, 1e-5);
        assert!(x1 < 1e-8, "{x1}");
        let top = c.displacement(100.0, 0.3); // half a revolution
        assert!((top - 2.0 * c.radius_m).abs() < 1e-12);
        assert!((c.nominal_shear_rate(100.0, 1e-3) - 45.0).abs() < 1e-9);
    }

    /// The velocity is the displacement's derivative: a central difference
    /// of step 1e-6 s agrees to 1e-7 m/s (its error is ẍ⃛ h²/6 ≈ 1e-10).
    #[test]
    fn crank_velocity_is_the_derivative_of_the_displacement() {
        let c = Crank::default();
        for t in [0.0, 0.013, 0.1, 0.2999, 0.41, 0.77] {
            let h = 1e-6;
            let numeric = (c.displacement(200.0, t + h) - c.displacement(200.0, t - h)) / (2.0 * h);
            assert!(
                (c.velocity(200.0, t) - numeric).abs() < 1e-7,
                "t {t}: {} vs {numeric}",
                c.velocity(200.0, t)
            );
        }
    }

    fn small_stand() -> SynthSettings {
        SynthSettings {
            rpms: vec![400.0],
            currents_a: vec![1.0],
            cycles: 1.0,
            rate_hz: 2000.0,
            ..SynthSettings::default()
        }
    }

    /// The extra force adds to the record and nothing else: the same seed
    /// gives the same sensor noise; a viscous force adds exactly c ẋ; a
    /// smooth force adds a path whose scale is the one asked (its sample sd
    /// over 300 samples with ℓ = 5 ms, about 40 independent stretches,
    /// within 40 %).
    #[test]
    fn the_extra_force_adds_to_the_law_and_noise() {
        let base = small_stand();
        let p = base.law.law().params_at(1.0);
        let plain = virtual_record(&base, &Truth::BodnerPartom(p), 400.0, 1.0, None, 0).unwrap();
        let viscous = SynthSettings {
            extra_force: ExtraForce { viscous_n_s_per_m: 500.0, ..ExtraForce::default() },
            ..base.clone()
        };
        let rec = virtual_record(&viscous, &Truth::BodnerPartom(p), 400.0, 1.0, None, 0).unwrap();
        assert_eq!(rec.displacement, plain.displacement);
        for k in 0..rec.time.len() {
            let added = rec.force[k] - plain.force[k];
            let expected = 500.0 * base.crank.velocity(400.0, rec.time[k]);
            assert!((added - expected).abs() < 1e-9, "sample {k}: {added} vs {expected}");
        }
        let rec =
            virtual_record(&base, &Truth::BodnerPartom(p), 400.0, 1.0, Some((80.0, 0.005)), 0)
                .unwrap();
        let added: Vec<f64> = rec.force.iter().zip(&plain.force).map(|(a, b)| a - b).collect();
        let mean = added.iter().sum::<f64>() / added.len() as f64;
        let sd =
            (added.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / added.len() as f64).sqrt();
        assert!((sd / 80.0 - 1.0).abs() < 0.4, "sd {sd}");
        // smooth: neighbours nearly equal (ℓ is 10 samples)
        let lag1 = added.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum::<f64>()
            / (sd * sd * added.len() as f64);
        assert!(lag1 > 0.9, "lag-1 correlation {lag1}");
    }

    /// A smooth force given for some crank speeds but not all is refused
    /// before anything is written.
    #[test]
    fn an_extra_force_of_the_wrong_length_is_refused() {
        let dir = std::env::temp_dir().join(format!("mrbp-synth-extra-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut s = SynthSettings { rpms: vec![100.0, 200.0, 400.0], ..small_stand() };
        s.extra_force.smooth_sd_n = vec![10.0, 20.0];
        s.extra_force.smooth_time_s = vec![0.01];
        let e = write_campaign(&s, &dir).unwrap_err().to_string();
        assert!(e.contains("2 values for 3 crank speeds"), "{e}");
        s.extra_force.smooth_sd_n = vec![10.0];
        s.extra_force.smooth_time_s = vec![];
        let e = write_campaign(&s, &dir).unwrap_err().to_string();
        assert!(e.contains("needs its time scale"), "{e}");
        assert!(!dir.exists());
    }

    /// Records loading would refuse, or that do not trace a loop, or that
    /// no machine holds, are refused before anything is written: 400 rpm
    /// sampled at 50 Hz (7.5 samples a revolution), one revolution at 100
    /// rpm and 20 Hz (12 samples a revolution, 13 in all: allowed) and
    /// at 150 rpm and 60 Hz with a tenth of a revolution (3 samples), and
    /// 10⁴ revolutions at 1 kHz of a 1 rpm crank (6·10⁸ samples).
    #[test]
    fn records_too_coarse_too_short_or_too_long_are_refused() {
        let dir = std::env::temp_dir().join(format!("mrbp-synth-sampling-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let s = SynthSettings { rate_hz: 50.0, ..small_stand() };
        let e = write_campaign(&s, &dir).unwrap_err().to_string();
        assert!(e.contains("7.500 samples a revolution") && e.contains("54 Hz"), "{e}");
        let s = SynthSettings { rate_hz: 20.0, rpms: vec![100.0], ..small_stand() };
        assert!(sampled_enough(&s, 100.0).is_ok());
        let s = SynthSettings { rate_hz: 60.0, rpms: vec![150.0], cycles: 0.1, ..small_stand() };
        let e = write_campaign(&s, &dir).unwrap_err().to_string();
        assert!(e.contains("give 3 samples") && e.contains("at least 10"), "{e}");
        let s = SynthSettings { rate_hz: 1000.0, rpms: vec![1.0], cycles: 1e4, ..small_stand() };
        let e = write_campaign(&s, &dir).unwrap_err().to_string();
        assert!(e.contains("6.000e8 samples"), "{e}");
        assert!(!dir.exists());
    }
}
