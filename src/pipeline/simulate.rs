//! A calibrated damper driven by an excitation of the user's own: the
//! force and its bands along a displacement history that has no measured
//! force (`mrbp simulate`).

use std::path::Path;
use std::time::Instant;

use super::{Event, Pipeline, PredictOptions};
use crate::calibrate::{command_line, Calibration};
use crate::data::table::ColumnMap;
use crate::data::{
    check_coil_current, loading_branches, same_current, Columns, Limits, Record, RecordPart, Run,
    RunData, RunSpec, Shear, MIN_SMOOTH_SAMPLES, REVERSAL_SHARE,
};
use crate::error::{Error, Result};
use crate::predict::bands;
use crate::store::simulation::{Simulation, SimulationRecord};

/// Where a simulation's draws come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Source {
    /// The calibration's posterior.
    Posterior,
    /// New tests of the damper from its between-run layer.
    NewTest,
}

/// How far a current-law simulation may reach beyond the calibrated
/// currents before it is refused (share of the calibrated span).
const EXTRAPOLATION_LIMIT: f64 = 0.5;

impl Pipeline<'_> {
    /// Posterior draws of `cal` along the displacement history in `input`
    /// (CSV or Parquet, `time_s`, `displacement_m` and optionally
    /// `current_a`; a force column, if any, is ignored) at `current` (else
    /// the file's current, else the calibration's own): the model and
    /// predictive bands of the stress and of the force into `out`
    /// (`simulation.parquet`, `simulation.toml`, a figure).
    /// With `new_test`, the draws are new tests of the damper from the
    /// folder's between-run layer (`between_runs.parquet`, `--per-run`),
    /// not the calibration's posterior: the band a test not yet run at this
    /// current would fall in.
    pub fn simulate(
        &mut self,
        cal: &Calibration,
        input: &Path,
        current: Option<f64>,
        out: &Path,
        options: &PredictOptions,
        new_test: bool,
    ) -> Result<Simulation> {
        let c = Columns::default();
        let record = Record::read(input, &ColumnMap::of(&c, false))?;
        let source = match new_test {
            true => Source::NewTest,
            false => Source::Posterior,
        };
        let simulation =
            self.simulation_from(cal, input, record, current, options, Some(out), source)?;
        crate::report::simulation::write(out, &simulation, &cal.label())?;
        crate::store::simulation::write(out, &simulation)?;
        let path = out.join(crate::store::simulation::FILE);
        self.emit(Event::Wrote(&path));
        Ok(simulation)
    }

    /// [`Pipeline::simulate`] of a record in memory (time, displacement and
    /// optionally current; its force is ignored) named by `input` in
    /// messages, without writing anything but holding `out` if given; with
    /// `new_test`, new tests of the damper from the folder's between-run
    /// layer, as `simulate --new-test`.
    #[allow(clippy::too_many_arguments)]
    pub fn simulation(
        &mut self,
        cal: &Calibration,
        input: &Path,
        record: Record,
        current: Option<f64>,
        options: &PredictOptions,
        out: Option<&Path>,
        new_test: bool,
    ) -> Result<Simulation> {
        let source = if new_test { Source::NewTest } else { Source::Posterior };
        self.simulation_from(cal, input, record, current, options, out, source)
    }

    /// [`Pipeline::simulation`] with the draws from `source`.
    #[allow(clippy::too_many_arguments)]
    fn simulation_from(
        &mut self,
        cal: &Calibration,
        input: &Path,
        mut record: Record,
        current: Option<f64>,
        options: &PredictOptions,
        out: Option<&Path>,
        source: Source,
    ) -> Result<Simulation> {
        options.check()?;
        let layer = match source {
            Source::Posterior => None,
            Source::NewTest if cal.is_current_law() => {
                return Err(Error::Usage(format!("--new-test draws new tests from the between-run layer of a per-current calibration; {} holds a law", cal.dir.display())))
            }
            Source::NewTest => Some(crate::store::between_runs::new_tests(&cal.dir, &cal.record.calibration_id, cal.settings.parameter_model().law(), &cal.sample.layout)?),
        };
        let c = Columns::default();
        let map = ColumnMap::of(&c, false);
        record.force = vec![f64::NAN; record.len()];
        record.check(input, &map)?;
        record.check_limits(input, &map, &Limits::default())?;
        let (current_a, range) = self.simulated_current(cal, input, &record, current)?;
        let varies = range.is_some();
        // a new test at a current the folder's calibration is not at: the
        // layer fitted again to the same runs alone, its centres' curve in
        // the current read at this one
        let refit = match (source, range) {
            (Source::NewTest, None) if !same_current(current_a, cal.record.current_a) => {
                Some(self.layer_at(cal, current_a)?)
            }
            _ => None,
        };
        let extrapolated = match (&refit, range) {
            (Some((_, outside)), _) => *outside,
            (None, Some((lo, hi))) => self.check_current(cal, lo)? | self.check_current(cal, hi)?,
            (None, None) => self.check_current(cal, current_a)?,
        };
        let geometry = match cal.record.geometry {
            Some(g) => g,
            None => cal.full_campaign()?.geometry,
        };
        let id = input
            .file_stem()
            .map_or_else(|| "input".to_string(), |s| s.to_string_lossy().into_owned());
        let shear = Shear::from_record(&record, &geometry, None);
        let branches = loading_branches(&record.displacement, REVERSAL_SHARE);
        // where the current changes, the coil's lag: the posterior's, or,
        // for a law calibrated without such records, its prior
        let coil_lag = match (varies, cal.sample.model.has_lag()) {
            (false, _) => CoilLag::None,
            (true, true) => CoilLag::Posterior,
            (true, false) => {
                self.note("the law was calibrated without records whose current changes, so its coil lag is not known: each draw takes one from the lag's prior (log-normal about 10 ms, a factor e either way; a damper coil settles in 5–30 ms), and the band carries it");
                CoilLag::Prior
            }
        };
        let spec = RunSpec {
            current_varies: varies,
            ..RunSpec::new(id.clone(), input.to_path_buf(), current_a)
        };
        let run = Run { spec, path: input.to_path_buf(), record, shear, branches, geometry };
        if let Some(out) = out {
            self.prepare(out, "--out", &[], &[], true)?;
        }
        let clock = Instant::now();
        // how far the excitation goes beyond what the records showed the law
        let records = records_reach(cal);
        let smooth_ms = cal.settings.likelihood.smooth_strain_ms;
        let input_interval = longest_interval(&run.shear.time);
        let smooth_ms = match records.map(|r| records_smoothing_s(smooth_ms, r.interval)) {
            // the smoother's least samples would span more of this
            // excitation than the records' smoothing did, and bend its own
            // turns (a 1 Hz stroke sampled at 20 Hz lost 3.5 % of its
            // amplitude): the excitation is taken as it is
            Some(span) if MIN_SMOOTH_SAMPLES as f64 * input_interval > 1.01 * span => {
                self.note(&format!(
                    "{} is sampled every {:.3} ms: the strain smoothing of the records ({:.3} ms either side) holds fewer than {MIN_SMOOTH_SAMPLES} of its samples, so the excitation drives the law as it is, unsmoothed (and the predictive band carries no displacement noise)",
                    input.display(),
                    1e3 * input_interval,
                    span * 1e3
                ));
                0.0
            }
            _ => smooth_ms,
        };
        // the excitation is the damper's own displacement: a stand's
        // channel lag (`displacement_lag_ms`) does not apply
        let data = RunData::from_run(&run, RecordPart::WholeRecord, smooth_ms);
        let mut draws: Vec<_> = match (&refit, &layer) {
            // new tests at the current asked for, from the layer fitted again
            (Some((fitted, _)), _) => {
                let group = fitted.group(current_a).ok_or_else(|| {
                    Error::Compute(format!(
                        "the between-run layer fitted again has no group at {current_a} A"
                    ))
                })?;
                let (tests, outside) =
                    fitted.new_tests(group, cal, &data, options.draws, options.seed);
                if tests.is_empty() {
                    return Err(Error::Compute(format!("no new test of the between-run layer at {current_a} A lies inside the calibrations' prior ({outside} draws tried)")));
                }
                tests
            }
            // new tests of the damper, spread evenly over the layer's draws
            (None, Some((tests, _))) => crate::posterior::evenly_spaced(tests.len(), options.draws)
                .into_iter()
                .map(|i| tests[i])
                .collect(),
            // the posterior with the typical noise level and force offset of the runs seen
            (None, None) => cal
                .draw_positions(options.draws)
                .iter()
                .map(|&(s, c)| cal.sample.draw_without(s, c, &id, current_a))
                .collect(),
        };
        if coil_lag == CoilLag::Prior {
            for (i, draw) in draws.iter_mut().enumerate() {
                if let Some((_, lag)) = draw.field.as_mut() {
                    let mut rng = crate::rng::stream(options.seed, &[LAG_STREAM, i as u64]);
                    *lag = crate::posterior::LAG_PRIOR.draw(&mut rng);
                }
            }
        }
        let own = Reach::of(&data);
        let beyond = records.map_or_else(Vec::new, |r| own.beyond(&r));
        if !beyond.is_empty() {
            let said: Vec<&str> = beyond.iter().map(|(_, said)| said.as_str()).collect();
            self.note(&format!(
                "warning: {} goes beyond the calibration's records: {}; the band extrapolates the law where no record checks it (simulation.toml: beyond_records)",
                input.display(),
                said.join("; ")
            ));
        }
        let mut settings = cal.predict_settings(options.replicates, options.seed);
        // an excitation sampled more coarsely than the records: sub-steps
        // as short as the calibration's (its step rule checked no longer)
        let finer = records.and_then(|r| sub_step_factor(own.interval, r.interval).map(|f| (r, f)));
        if let Some((records, finer)) = finer {
            let integrator = &mut settings.integrator;
            self.note(&format!(
                "{} is sampled every {:.3} ms, {:.1}× the records' {:.3} ms: the integrator takes {} sub-steps per sample instead of the calibration's {}, so that no sub-step is longer than those its step rule checked",
                input.display(),
                1e3 * own.interval,
                own.interval / records.interval,
                1e3 * records.interval,
                integrator.substeps * finer,
                integrator.substeps
            ));
            integrator.substeps *= finer;
            integrator.max_substeps = integrator.max_substeps.saturating_mul(finer);
        }
        let bar = self.bar(draws.len() as u64);
        let b = bands(&data, 0, &draws, &settings, &|| bar.inc(1))?;
        bar.finish_and_clear();
        let record = SimulationRecord {
            mrbp_version: env!("CARGO_PKG_VERSION").to_string(),
            command: command_line(),
            input: input.display().to_string(),
            current_a,
            current_varies: varies,
            area_m2: geometry.area_m2,
            draws: b.draws,
            failed_draws: b.failed,
            noise_replicates: options.replicates,
            seed: options.seed,
            seconds: clock.elapsed().as_secs_f64(),
            calibration_id: cal.record.calibration_id.clone(),
            extrapolated,
            layer_runs: layer.map(|(_, runs)| runs).unwrap_or_default(),
            coil_lag: coil_lag.name().to_string(),
            peak_velocity_m_s: own.velocity,
            stroke_m: own.stroke,
            records_peak_velocity_m_s: records.map_or(f64::NAN, |r| r.velocity),
            records_stroke_m: records.map_or(f64::NAN, |r| r.stroke),
            beyond_records: beyond.iter().map(|(name, _)| name.to_string()).collect(),
            substeps: settings.integrator.substeps,
        };
        if b.failed > 0 {
            self.note(&format!(
                "{} of {} posterior draws could not be integrated along {} (left out of the bands)",
                b.failed,
                b.failed + b.draws,
                input.display()
            ));
        }
        let current = data.current.clone().unwrap_or_else(|| vec![current_a; data.time.len()]);
        Ok(Simulation {
            time: data.time.clone(),
            displacement: run.record.displacement.clone(),
            current,
            gamma_model: data.gamma.clone(),
            model: b.model,
            predictive: b.predictive,
            record,
        })
    }

    /// The current to simulate at, and its lowest and highest where it
    /// changes along the excitation: the option, else the file's (a law
    /// follows it where it changes; one parameter set cannot), else a
    /// per-current calibration's own. Where it changes, the current
    /// returned is its mean.
    fn simulated_current(
        &mut self,
        cal: &Calibration,
        input: &Path,
        record: &Record,
        current: Option<f64>,
    ) -> Result<(f64, Option<(f64, f64)>)> {
        let column = Columns::default().current;
        let from_file = match &record.current {
            None => None,
            Some(values) => {
                let (lo, hi) = values
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
                let mid = 0.5 * (lo + hi);
                if !same_current(lo, mid) || !same_current(hi, mid) {
                    if !cal.is_current_law() {
                        return Err(Error::input_at(
                            input,
                            None,
                            Some(&column),
                            format!(
                                "the current changes within the record ({lo} to {hi} A): the calibration in {} has one parameter set, at {} A; a law (mrbp sample --model current-curves or current-law) follows a changing current",
                                cal.dir.display(),
                                cal.record.current_a
                            ),
                        ));
                    }
                    check_coil_current(input, &column, values)?;
                    if lo <= 0.0
                        && cal.sample.model.kind() == crate::posterior::ModelKind::CurrentLaw
                    {
                        return Err(Error::Usage(format!(
                            "the current of {} reaches 0 A, where the current law has no yield stress (R0, R1, D1 ∝ s(I)); the current curves (--model current-curves) have an off-state",
                            input.display()
                        )));
                    }
                    if let Some(c) = current {
                        return Err(Error::Usage(format!("--current {c} names one current, but the column {column} of {} changes ({lo} to {hi} A): leave --current out to follow it", input.display())));
                    }
                    return Ok((values.iter().sum::<f64>() / values.len() as f64, Some((lo, hi))));
                }
                Some(mid)
            }
        };
        let one = match (current, from_file) {
            (Some(c), Some(f)) if !same_current(c, f) => Err(Error::Usage(format!("--current {c} disagrees with the {f} A of the column {column} in {}", input.display()))),
            (Some(c), _) => Ok(c),
            (None, Some(f)) => Ok(f),
            (None, None) if cal.is_current_law() => Err(Error::Usage(format!(
                "{} has no {column} column: give the current to simulate with --current (the law was calibrated at {:?} A)",
                input.display(),
                cal.record.currents
            ))),
            (None, None) => Ok(cal.record.current_a),
        };
        one.map(|c| (c, None))
    }

    /// The between-run layer of `cal`'s folder fitted again to the same runs
    /// alone (their folders as `between_runs.parquet` names them), with the
    /// same Gibbs settings and seed, predicting `current_a` too; and whether
    /// that current lies outside the calibrated ones. Refused where the
    /// runs are at one current only, or `current_a` is further from them
    /// than [`EXTRAPOLATION_LIMIT`] of their span.
    fn layer_at(
        &mut self,
        cal: &Calibration,
        current_a: f64,
    ) -> Result<(crate::validate::between_runs::BetweenRuns, bool)> {
        use crate::validate::between_runs::{BetweenRuns, GibbsSettings, LayerRun};
        let folders =
            crate::store::between_runs::layer_folders(&cal.dir, &cal.record.calibration_id)?;
        let alone: Vec<Calibration> =
            folders.iter().map(|f| crate::store::folder::read(f)).collect::<Result<_>>()?;
        let mut runs = Vec::with_capacity(alone.len());
        for one in &alone {
            let campaign = one.used_runs(&one.full_campaign()?);
            let run = campaign.runs.first().cloned().ok_or_else(|| {
                Error::input(&one.dir, "a calibration alone without its run".to_string())
            })?;
            let lik = &one.settings.likelihood;
            runs.push((lik.run_data(&run, lik.part), run));
        }
        let layer_runs: Vec<LayerRun> = alone
            .iter()
            .zip(&runs)
            .map(|(one, (data, run))| LayerRun {
                id: run.id(),
                current_a: run.spec.current_a,
                cal: one,
                data,
            })
            .collect();
        let (lo, hi) = layer_runs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), r| {
            (l.min(r.current_a), h.max(r.current_a))
        });
        if !(hi > lo) {
            return Err(Error::Usage(format!(
                "the between-run layer in {} has runs at {lo} A only: a new test at {current_a} A needs runs at two currents or more (its curve in the current)",
                cal.dir.display()
            )));
        }
        let outside = within_reach(current_a, (lo, hi), "the runs were", "a new test")?;
        let clock = Instant::now();
        let layer = BetweenRuns::fit(
            &layer_runs,
            &[current_a],
            GibbsSettings::default(),
            cal.settings.sampler.seed,
        )?;
        self.note(&format!(
            "a new test at {current_a} A, {} the calibrated currents {lo}–{hi} A: the between-run layer fitted again to its {} runs alone, its centres read off their curve in the current ({:.1} s; largest R̂ {:.4}, smallest ESS {:.0}){}",
            if outside {
                "outside"
            } else if layer_runs.iter().any(|r| same_current(r.current_a, current_a)) {
                "at one of"
            } else {
                "between"
            },
            layer_runs.len(),
            clock.elapsed().as_secs_f64(),
            layer.max_rhat,
            layer.min_ess,
            if crate::validate::between_runs::settled(layer.max_rhat, layer.min_ess) { "" } else { " — not converged: the band is not to be trusted" }
        ));
        Ok((layer, outside))
    }

    /// Refuses a current the calibration does not cover; returns whether a
    /// current law extrapolates to it (with a note).
    fn check_current(&mut self, cal: &Calibration, current_a: f64) -> Result<bool> {
        if !cal.is_current_law() {
            finite_current(current_a)?;
            let own = cal.record.current_a;
            if !same_current(current_a, own) {
                // only the B-P law has a law in the current
                let other = match cal.settings.law.is_bodner_partom() {
                    true => "a current law (mrbp sample --model current-law) simulates other currents".to_string(),
                    false => format!("the {} law is calibrated per current: calibrate it on records at {current_a} A", cal.settings.law.name()),
                };
                return Err(Error::Usage(format!(
                    "the calibration in {} is at {own} A and cannot simulate {current_a} A; {other}",
                    cal.dir.display()
                )));
            }
            return Ok(false);
        }
        let (lo, hi) = cal.current_range();
        let outside = within_reach(current_a, (lo, hi), "the law was", "it")?;
        if outside {
            self.note(&format!("{current_a} A is outside the calibrated currents {lo}–{hi} A: the current law extrapolates (simulation.toml says so)"));
        }
        Ok(outside)
    }
}

/// Refuses a current that is not a finite number ≥ 0 A.
fn finite_current(current_a: f64) -> Result<()> {
    match current_a.is_finite() && current_a >= 0.0 {
        true => Ok(()),
        false => {
            Err(Error::Usage(format!("the current must be a finite number ≥ 0 A, got {current_a}")))
        }
    }
}

/// Refuses a current that is not a finite number ≥ 0 A, or lies further
/// from the calibrated currents `lo`–`hi` than [`EXTRAPOLATION_LIMIT`] of
/// their span (the message says `who` … calibrated there and how far
/// `what` may reach); returns whether it lies outside them.
fn within_reach(current_a: f64, (lo, hi): (f64, f64), who: &str, what: &str) -> Result<bool> {
    finite_current(current_a)?;
    let reach = EXTRAPOLATION_LIMIT * (hi - lo);
    if current_a < lo - reach || current_a > hi + reach {
        return Err(Error::Usage(format!(
            "{current_a} A is far outside the currents {who} calibrated at ({lo}–{hi} A; {what} may reach {:.3}–{:.3} A): calibrate at currents around it",
            (lo - reach).max(0.0),
            hi + reach
        )));
    }
    Ok(current_a < lo - 1e-9 || current_a > hi + 1e-9)
}

/// Where a simulation's coil lag comes from ([`SimulationRecord::coil_lag`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum CoilLag {
    /// The current does not change: no lag acts.
    None,
    /// The law's posterior (calibrated on records whose current changes).
    Posterior,
    /// [`crate::posterior::LAG_PRIOR`], a draw for each posterior draw.
    Prior,
}

impl CoilLag {
    fn name(self) -> &'static str {
        match self {
            CoilLag::None => "",
            CoilLag::Posterior => "posterior",
            CoilLag::Prior => "prior",
        }
    }
}

/// The random stream of the coil lags drawn from their prior (with the
/// simulation's seed and the draw's index).
const LAG_STREAM: u64 = 0x0c01_11a9;

/// How far an excitation beyond the calibration's records is flagged:
/// its peak velocity or stroke more than this many times theirs.
const BEYOND_RECORDS: f64 = 1.25;

/// The reach of a record as the law sees it (the strain smoothed as in
/// calibration, times the gap): its peak speed (m/s, central differences)
/// and its stroke (m, half the range of the displacement).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Reach {
    velocity: f64,
    stroke: f64,
    /// The longest sample interval (s).
    interval: f64,
}

impl Reach {
    fn of(data: &RunData) -> Reach {
        let x: Vec<f64> = data.gamma.iter().map(|g| g * data.gap_m).collect();
        let velocity = (1..x.len().saturating_sub(1))
            .map(|i| ((x[i + 1] - x[i - 1]) / (data.time[i + 1] - data.time[i - 1])).abs())
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        let (lo, hi) =
            x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
        Reach { velocity, stroke: 0.5 * (hi - lo), interval: longest_interval(&data.time) }
    }

    /// The larger of two reaches, quantity by quantity.
    fn max(self, other: Reach) -> Reach {
        Reach {
            velocity: self.velocity.max(other.velocity),
            stroke: self.stroke.max(other.stroke),
            interval: self.interval.max(other.interval),
        }
    }

    /// What of this reach lies beyond `records`' by more than
    /// [`BEYOND_RECORDS`]: its name (`velocity`, `stroke`) and the numbers
    /// in words.
    fn beyond(&self, records: &Reach) -> Vec<(&'static str, String)> {
        let mut out = Vec::new();
        if self.velocity > BEYOND_RECORDS * records.velocity {
            out.push((
                "velocity",
                format!(
                    "its peak velocity {:.3} m/s is {:.1}× the fastest record's ({:.3} m/s)",
                    self.velocity,
                    self.velocity / records.velocity,
                    records.velocity
                ),
            ));
        }
        if self.stroke > BEYOND_RECORDS * records.stroke {
            out.push((
                "stroke",
                format!(
                    "its stroke ±{:.1} mm is {:.1}× the longest record's (±{:.1} mm)",
                    1e3 * self.stroke,
                    self.stroke / records.stroke,
                    1e3 * records.stroke
                ),
            ));
        }
        out
    }
}

/// How many times the calibration's sub-steps an excitation whose longest
/// sample interval is `own` needs so that none is longer than on records
/// whose longest is `records` (s): `None` where it needs no more (a
/// hundredth's slack, for the clocks' rounding).
fn sub_step_factor(own: f64, records: f64) -> Option<u32> {
    let ratio = own / records;
    (ratio.is_finite() && ratio > 1.01).then(|| (ratio - 0.01).ceil().min(u32::MAX as f64) as u32)
}

/// The longest interval between samples at `time` (s).
fn longest_interval(time: &[f64]) -> f64 {
    time.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max)
}

/// The half-width (s) over which the strain of records sampled every
/// `interval` s was smoothed with `smooth_ms` ([`crate::data::smoothed_strain`]:
/// at least [`MIN_SMOOTH_SAMPLES`] samples either side; 0 unsmoothed).
fn records_smoothing_s(smooth_ms: f64, interval: f64) -> f64 {
    match smooth_ms > 0.0 {
        true => (1e-3 * smooth_ms).max(MIN_SMOOTH_SAMPLES as f64 * interval),
        false => 0.0,
    }
}

/// The reach of the records `cal` was calibrated on, quantity by quantity
/// the largest; `None` where they cannot be read (the manifest moved).
fn records_reach(cal: &Calibration) -> Option<Reach> {
    let campaign = cal.used_runs(&cal.full_campaign().ok()?);
    let smooth = cal.settings.likelihood.smooth_strain_ms;
    campaign
        .runs
        .iter()
        .map(|run| Reach::of(&RunData::from_run(run, RecordPart::WholeRecord, smooth)))
        .reduce(Reach::max)
}
