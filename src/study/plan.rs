//! A study as data: its tasks (each one calibration fully specified), how
//! a design becomes them, and the files that hold them (`study.toml`,
//! `tasks.csv`, `tasks/<id>/task.toml`), written and read.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::calibrate::CalibrationSettings;
use crate::error::{Error, Result};
use crate::model::{Params, PARAM_NAMES};
use crate::noise::{discrepancy::Discrepancy, NoiseKind, NoiseOptions};
use crate::synth::{run_id, Damper, ExtraForce, StandLaw, SynthSettings};

/// Where a task's records come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Source {
    /// A virtual campaign, made by the task from these settings.
    Synthetic { synth: Box<SynthSettings> },
    /// A campaign on disk.
    Campaign { manifest: PathBuf },
}

/// One calibration of a study.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskSpec {
    pub id: String,
    pub study: String,
    pub source: Source,
    /// The current calibrated (the campaign's only one if not given).
    pub current_a: Option<f64>,
    /// What is known of the truth: coordinate name → value (SI), for the
    /// virtual campaigns.
    #[serde(default)]
    pub truth: BTreeMap<String, f64>,
    pub settings: CalibrationSettings,
}

/// The study as a whole.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyRecord {
    pub name: String,
    pub kind: String,
    pub tasks: usize,
    pub mrbp_version: String,
    pub command: String,
}

/// What a study is made of, before it is written.
#[derive(Clone, Debug)]
pub enum Design {
    /// `n` noise realisations of one virtual campaign (known parameters):
    /// how often credible intervals hold the truth.
    Replicates { n: usize, synth: SynthSettings },
    /// Simulation-based calibration: `n` virtual campaigns whose B-P
    /// parameters and noise level are drawn from the calibration's own
    /// prior; the rank of each truth among posterior draws is uniform if
    /// the posterior is right.
    Sbc { n: usize, synth: SynthSettings },
    /// Every current of every campaign (or the given ones): a fleet, a
    /// sweep.
    Campaigns { manifests: Vec<PathBuf>, currents: Vec<f64> },
}

/// `mrbp study plan`'s options: the design, how its virtual campaigns are
/// made, and the calibration's settings.
#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("design").required(true).args(["replicates", "sbc", "campaigns"])))]
pub struct PlanOptions {
    /// Name of the study (default: the folder's name)
    #[arg(long)]
    pub name: Option<String>,
    /// N noise realisations of a virtual campaign with known parameters
    /// (coverage of the credible intervals)
    #[arg(long, value_name = "N")]
    pub replicates: Option<usize>,
    /// Simulation-based calibration: N virtual campaigns with parameters and
    /// noise drawn from the calibration's prior (--config)
    #[arg(long, value_name = "N")]
    pub sbc: Option<usize>,
    /// Calibrate this campaign at each of its currents (or at --current);
    /// repeat for a fleet
    #[arg(long = "campaign", value_name = "MANIFEST")]
    pub campaigns: Vec<PathBuf>,
    /// The virtual stand's settings (the synth.toml format) for --replicates
    /// and --sbc; the options below override it (default: the bundled
    /// campaign's stand at one current, --current or 1 A)
    #[arg(long, value_name = "FILE")]
    pub synth_config: Option<PathBuf>,
    /// Seed of the stand's sensor noise in the first task (task k: + k;
    /// default: that of the bundled campaign). --seed is the sampler's.
    #[arg(long, value_name = "SEED")]
    pub noise_seed: Option<u64>,
    /// Calibrate only the runs at this coil current (A)
    #[arg(long)]
    pub current: Option<f64>,
    #[command(flatten)]
    pub synth: crate::synth::Overrides,
    #[command(flatten)]
    pub sample: crate::calibrate::settings::Overrides,
}

impl PlanOptions {
    /// What the user should know of the study planned, before running it:
    /// an SBC drawn from the default priors (no `--config`).
    pub fn notes(&self) -> Vec<String> {
        match (self.sbc, &self.sample.config) {
            (Some(_), None) => vec![
                "note: --sbc draws from the calibration's own priors, here the defaults (no --config): they span decades, down to noise levels far below any force sensor's, and where the noise drawn is below the virtual stand's own discretisation (its velocity read off the samples, about 1e-5 of the force) the ranks of σ fail for that reason, not the sampler's; a settings file with priors narrowed to a realistic box (studies/sbc-prior.toml, studies/sbc-prior-bp-spencer.toml) makes the study docs/calibration.md reports".to_string(),
            ],
            _ => Vec::new(),
        }
    }

    /// Writes the study these options describe into `dir`: its name and tasks.
    pub fn plan(&self, dir: &Path) -> Result<(String, Vec<TaskSpec>)> {
        if self.sample.model.is_some() {
            return Err(Error::Usage("study plan: --model is not an option of a study (each task calibrates one current)".into()));
        }
        let settings = self.sample.settings()?;
        let synth = || -> Result<SynthSettings> {
            // the records are of the law the calibrations take (--law, or
            // the settings file's `law`)
            let law = self.sample.law.first().copied();
            let synth = crate::synth::Overrides {
                law: law.or((!settings.law.is_bodner_partom()).then_some(settings.law)),
                ..self.synth.clone()
            };
            let mut s = synth.settings(self.synth_config.as_deref(), self.noise_seed)?;
            if self.synth_config.is_none() && self.synth.currents.is_none() {
                s.currents_a = vec![self.current.unwrap_or(1.0)];
            }
            Ok(s)
        };
        let design = match (self.replicates, self.sbc) {
            (Some(n), _) => Design::Replicates { n, synth: synth()? },
            (_, Some(n)) => Design::Sbc { n, synth: synth()? },
            _ => Design::Campaigns {
                manifests: self.campaigns.clone(),
                currents: self.current.into_iter().collect(),
            },
        };
        let name = match &self.name {
            Some(n) => n.clone(),
            None => dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| "study".into()),
        };
        let tasks = plan(dir, &name, &design, &settings)?;
        Ok((name, tasks))
    }
}

/// The folder of task `id`.
pub fn task_dir(study: &Path, id: &str) -> PathBuf {
    study.join("tasks").join(id)
}

/// Writes the study `name` of `design` into `dir` (which must not hold a
/// study yet); the sampler seed of task k is the settings' seed + k.
pub fn plan(
    dir: &Path,
    name: &str,
    design: &Design,
    settings: &CalibrationSettings,
) -> Result<Vec<TaskSpec>> {
    if dir.join("study.toml").exists() {
        return Err(Error::Usage(format!(
            "{} already holds a study (study.toml): plan into a new folder",
            dir.display()
        )));
    }
    if name.is_empty() || name.contains(['/', '=', '\\']) {
        return Err(Error::Usage(format!(
            "study name {name:?}: use letters, digits, '-', '_' or '.'"
        )));
    }
    let specs = tasks_of(name, design, settings)?;
    if specs.is_empty() {
        return Err(Error::Usage("the study has no task".into()));
    }
    for spec in &specs {
        let text =
            toml::to_string(spec).map_err(|e| Error::Compute(format!("task {}: {e}", spec.id)))?;
        crate::atomic::write(&task_dir(dir, &spec.id).join("task.toml"), text.as_bytes())?;
    }
    let ids: String = specs.iter().map(|s| format!("{}\n", s.id)).collect();
    crate::atomic::write(&dir.join("tasks.csv"), format!("task\n{ids}").as_bytes())?;
    let kind = match design {
        Design::Replicates { .. } => "replicates",
        Design::Sbc { .. } => "sbc",
        Design::Campaigns { .. } => "campaigns",
    };
    let record = StudyRecord {
        name: name.into(),
        kind: kind.into(),
        tasks: specs.len(),
        mrbp_version: env!("CARGO_PKG_VERSION").into(),
        command: crate::store::command_line(),
    };
    let text = toml::to_string(&record).map_err(|e| Error::Compute(format!("study.toml: {e}")))?;
    crate::atomic::write(&dir.join("study.toml"), text.as_bytes())?;
    Ok(specs)
}

fn tasks_of(name: &str, design: &Design, settings: &CalibrationSettings) -> Result<Vec<TaskSpec>> {
    let id = |k: usize, n: usize| format!("t{k:0width$}", width = n.to_string().len().max(3));
    let seeded = |k: usize| {
        let mut s = settings.clone();
        s.sampler.seed = settings.sampler.seed + k as u64;
        s
    };
    let synthetic = |k: usize,
                     n: usize,
                     synth: SynthSettings,
                     settings: CalibrationSettings|
     -> Result<TaskSpec> {
        let current = *synth
            .currents_a
            .first()
            .ok_or_else(|| Error::Usage("a virtual study needs one current (--currents)".into()))?;
        if synth.currents_a.len() != 1 {
            return Err(Error::Usage(format!(
                "a virtual study calibrates one current; --currents gives {:?}",
                synth.currents_a
            )));
        }
        crate::synth::check_sampling(&synth)?;
        Ok(TaskSpec {
            id: id(k, n),
            study: name.into(),
            truth: truth_of(&synth, current)?,
            source: Source::Synthetic { synth: Box::new(synth) },
            current_a: Some(current),
            settings,
        })
    };
    match design {
        Design::Replicates { n, synth } => (0..*n)
            .map(|k| {
                synthetic(
                    k,
                    *n,
                    SynthSettings { seed: synth.seed + k as u64, ..synth.clone() },
                    seeded(k),
                )
            })
            .collect(),
        Design::Sbc { n, synth } => {
            let priors = settings.priors();
            let (s_lo, s_hi) = settings.sigma_bounds_pa;
            let discrepancy = (settings.likelihood.noise == NoiseKind::Discrepancy).then(|| {
                Discrepancy::new(&NoiseOptions {
                    sigma_bounds: settings.sigma_bounds_pa,
                    discrepancy: settings.likelihood.discrepancy.clone(),
                    ..NoiseOptions::default()
                })
            });
            (0..*n)
                .map(|k| {
                    // θ and σ from the prior the calibration uses, as SBC requires
                    let mut rng = crate::rng::stream(settings.sampler.seed, &[0x5bc, k as u64]);
                    let theta: Vec<f64> = priors.iter().map(|p| p.draw(&mut rng)).collect();
                    let sigma = crate::posterior::Prior::LogUniform { lower: s_lo, upper: s_hi }
                        .draw(&mut rng);
                    let current = synth.currents_a.first().copied().unwrap_or(1.0);
                    let mut s = SynthSettings {
                        noise_force_n: sigma * synth.geometry.area_m2,
                        seed: synth.seed + k as u64,
                        ..synth.clone()
                    };
                    // the stand's law passes through θ at the task's current
                    if settings.law.is_bodner_partom() {
                        let theta: [f64; 7] = std::array::from_fn(|i| theta[i]);
                        s.law.at_1a = at_reference(&synth.law, Params::from_array(theta), current);
                    } else {
                        s.damper = Some(Damper::through(
                            settings.law, &theta, current, synth.law.saturation_a,
                        ));
                    }
                    if let Some(model) = &discrepancy {
                        // each run's discrepancy from its prior: a path of the
                        // model's own process, its scale and time scale drawn
                        let area = synth.geometry.area_m2;
                        let (sd, ell): (Vec<f64>, Vec<f64>) = synth
                            .rpms
                            .iter()
                            .map(|rpm| {
                                let (lo, hi) = model.scale_bounds_at(0.0);
                                let sd =
                                    crate::posterior::Prior::LogUniform { lower: lo, upper: hi }
                                        .draw(&mut rng);
                                let (lo, hi) =
                                    model.time_bounds_at(1.0 / synth.rate_hz, 60.0 / rpm);
                                (
                                    sd * area,
                                    crate::posterior::Prior::LogUniform { lower: lo, upper: hi }
                                        .draw(&mut rng),
                                )
                            })
                            .unzip();
                        s.extra_force = ExtraForce {
                            smooth_sd_n: sd,
                            smooth_time_s: ell,
                            kernel: settings.likelihood.discrepancy.kernel,
                            viscous_n_s_per_m: 0.0,
                        };
                    }
                    synthetic(k, *n, s, seeded(k))
                })
                .collect()
        }
        Design::Campaigns { manifests, currents } => {
            let mut specs = Vec::new();
            for manifest in manifests {
                let campaign = crate::data::Campaign::load(manifest)?;
                let wanted: Vec<f64> = if currents.is_empty() {
                    campaign.currents()
                } else {
                    currents.iter().copied().filter(|c| campaign.has_current(*c)).collect()
                };
                let manifest = std::fs::canonicalize(manifest).unwrap_or_else(|_| manifest.clone());
                for c in wanted {
                    specs.push((manifest.clone(), c));
                }
            }
            let n = specs.len();
            Ok(specs
                .into_iter()
                .enumerate()
                .map(|(k, (manifest, c))| TaskSpec {
                    id: id(k, n),
                    study: name.into(),
                    source: Source::Campaign { manifest },
                    current_a: Some(c),
                    truth: BTreeMap::new(),
                    settings: seeded(k),
                })
                .collect())
        }
    }
}

/// The stand's reference parameters that give `theta` at `current` (the
/// stand's law scales R0, R1, D1 and G with the current).
fn at_reference(law: &StandLaw, theta: Params, current: f64) -> Params {
    let at = law.law().params_at(current).to_array();
    let reference = law.at_1a.to_array();
    let t = theta.to_array();
    Params::from_array(std::array::from_fn(|i| {
        if at[i] != 0.0 {
            t[i] * reference[i] / at[i]
        } else {
            t[i]
        }
    }))
}

/// The true coordinates of a virtual campaign at `current`: the B-P
/// parameters (or the damper law's, `[damper]`), every run's noise level σ = force noise / area, and where
/// the stand adds a smooth force and nothing else beyond the law, every
/// run's discrepancy scale (Pa) and time scale (s).
fn truth_of(synth: &SynthSettings, current: f64) -> Result<BTreeMap<String, f64>> {
    let mut truth: BTreeMap<String, f64> = match &synth.damper {
        // another damper law: its parameters at the task's current, by name
        Some(damper) => {
            let values = damper.values_at(current, synth.law.saturation_a)?;
            let law = damper.law.law();
            law.names().iter().zip(values).map(|(n, v)| (n.to_string(), v)).collect()
        }
        None => {
            let params = synth.law.law().params_at(current).to_array();
            PARAM_NAMES.iter().zip(params).map(|(n, v)| (n.to_string(), v)).collect()
        }
    };
    let extra = &synth.extra_force;
    for (i, rpm) in synth.rpms.iter().enumerate() {
        let run = run_id(current, *rpm);
        truth.insert(format!("sigma_{run}"), synth.noise_force_n / synth.geometry.area_m2);
        if let (Some((sd, ell)), 0.0) =
            (extra.smooth(i, synth.rpms.len())?, extra.viscous_n_s_per_m)
        {
            truth.insert(format!("discrepancy_sd_{run}"), sd / synth.geometry.area_m2);
            truth.insert(format!("discrepancy_time_{run}"), ell);
        }
    }
    Ok(truth)
}

/// The task ids of the study in `dir`, in order.
pub fn task_ids(dir: &Path) -> Result<Vec<String>> {
    let path = dir.join("tasks.csv");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        Error::input(
            &path,
            format!("cannot read ({e}): is {} a study folder (mrbp study plan)?", dir.display()),
        )
    })?;
    Ok(text.lines().skip(1).map(str::trim).filter(|l| !l.is_empty()).map(String::from).collect())
}

/// The study's record.
pub fn read_record(dir: &Path) -> Result<StudyRecord> {
    let path = dir.join("study.toml");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        Error::input(
            &path,
            format!("cannot read ({e}): is {} a study folder (mrbp study plan)?", dir.display()),
        )
    })?;
    toml::from_str(&text)
        .map_err(|e| Error::input(&path, format!("not a study record: {}", e.message())))
}

/// Task `id` of the study in `dir`.
pub fn read_task(dir: &Path, id: &str) -> Result<TaskSpec> {
    if id.is_empty() || id.contains(['/', '\\']) || id.starts_with('.') {
        return Err(Error::Usage(format!("task id {id:?} is not one of tasks.csv")));
    }
    let path = task_dir(dir, id).join("task.toml");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        Error::input(
            &path,
            format!(
                "cannot read ({e}): no task {id} in {} (a folder of mrbp study plan)",
                dir.display()
            ),
        )
    })?;
    toml::from_str(&text).map_err(|e| Error::input(&path, format!("not a task: {}", e.message())))
}
