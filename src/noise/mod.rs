//! Noise models: how a force record scatters about the model, one model a
//! file behind one trait, [`NoiseModel`].
//!
//! A noise model has parameters of its own for every run (a scale σ, a
//! correlation ρ, …) and answers every question about them, so that the
//! likelihood, the MAP search, the bands, the pointwise terms and
//! leave-one-out never ask which model they hold:
//!
//! | question | method |
//! |---|---|
//! | the parameters: names, units, coordinates, pooling over runs | [`NoiseModel::parameters`] |
//! | their prior, and their spread at the start of sampling | [`NoiseModel::log_prior`], [`NoiseModel::laplace_sd`] |
//! | the log-likelihood of a run's residuals, in the integrator's lanes | [`NoiseModel::scorer`] |
//! | conditional pointwise terms and a replicated record of one draw | [`NoiseModel::pointwise`] |
//! | a new record's noise and its marginal density (predictive bands) | [`NoiseModel::simulator`], [`NoiseModel::marginal_ln_pdf`] |
//! | the noise fitted to residuals and their whitening (the MAP) | [`NoiseModel::profile`] |
//! | a run's likelihood with its noise profiled out (leave-one-out) | [`NoiseModel::profile_log_likelihood`] |
//!
//! **Adding a noise model**: a file here with a type that implements
//! [`NoiseModel`] and has `fn new(&NoiseOptions) -> Self`, and its line in
//! the [`registry!`] at the end of this file (which also makes its name an
//! option of `--noise` and a value of `[likelihood] noise`).

pub mod ar1;
pub mod discrepancy;
pub mod gaussian;
pub mod model;
pub mod student_t;

pub use model::*;

use std::sync::Arc;

use serde::{Deserialize, Serialize};

/// The registry: every noise model, by the name the command line and the
/// settings files give it.
macro_rules! registry {
    ($($(#[$attr:meta])* $variant:ident => $model:ty,)+) => {
        /// A noise model by name (`--noise`, `[likelihood] noise`).
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
        #[serde(rename_all = "kebab-case")]
        pub enum NoiseKind {
            $($(#[$attr])* $variant,)+
        }

        impl NoiseKind {
            /// The model of this name with `options`.
            pub fn model(self, options: &NoiseOptions) -> Arc<dyn NoiseModel> {
                match self {
                    $(NoiseKind::$variant => Arc::new(<$model>::new(options)),)+
                }
            }

            /// Every noise model.
            pub const ALL: &'static [NoiseKind] = &[$(NoiseKind::$variant,)+];
        }
    };
}

registry! {
    /// Independent Gaussian residuals, one unknown σ per run; with errors in
    /// variables (the default) the strain's noise joins them.
    #[serde(alias = "Gaussian")]
    Gaussian => gaussian::Gaussian,
    /// Independent Student-t residuals (fixed ν), one unknown scale per run:
    /// robust to outliers.
    #[serde(alias = "StudentT")]
    StudentT => student_t::StudentT,
    /// AR(1) residuals, one unknown innovation σ and lag-one correlation ρ
    /// per run: for dense records whose residuals are correlated, where an
    /// independent model claims far too much certainty.
    #[serde(alias = "Ar1")]
    Ar1 => ar1::Ar1,
    /// Model discrepancy: a smooth force the law lacks (a Gaussian process
    /// in time, Matérn kernel, per run its scale and time scale) plus white
    /// noise; the Kalman filter's exact likelihood.
    Discrepancy => discrepancy::Discrepancy,
}

/// The unit of a noise coordinate named `<parameter>_<run>`, if it is one.
pub fn unit_of(name: &str) -> Option<&'static str> {
    let options = NoiseOptions::default();
    NoiseKind::ALL
        .iter()
        .flat_map(|k| k.model(&options).parameters())
        .find(|p| name.strip_prefix(p.name).is_some_and(|rest| rest.starts_with('_')))
        .map(|p| p.unit)
}

#[cfg(test)]
pub(crate) mod testing {
    //! What every model's tests share: a run with two branches and a
    //! yielding path, and the pointwise terms summed.

    use super::*;
    use crate::data::RunData;
    use crate::model::LANES;

    /// A short run with two branches and a path that yields (so the
    /// tangent stiffness varies), its residuals about the path irregular.
    pub fn run(strain_noise_var: f64) -> (RunData, Vec<f64>) {
        let n = 41;
        let time: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
        let gamma: Vec<f64> = (0..n).map(|k| 0.02 * (k as f64 * 0.15).sin()).collect();
        let path: Vec<f64> = gamma.iter().map(|g| 4e4 * (g / 0.01).tanh()).collect();
        let tau: Vec<f64> = path
            .iter()
            .enumerate()
            .map(|(k, p)| p + 300.0 * ((k as f64) * 1.7).sin() + 120.0 * ((k as f64) * 0.31).cos())
            .collect();
        let run = RunData::new(
            "r".into(),
            time,
            gamma,
            tau,
            path[0],
            1.0,
            (1.0, 1.0),
            (strain_noise_var, 0.3),
        );
        (run, path)
    }

    /// The log-likelihood a model's scorer gives `run` at `coordinates`
    /// (every lane alike), with the residuals about `path`.
    pub fn scored(
        model: &dyn NoiseModel,
        run: &RunData,
        path: &[f64],
        coordinates: NoiseValues,
        g: f64,
    ) -> f64 {
        let stiffness = stiffness_path(run, path, g);
        let mut scorer = model.scorer(run, &[coordinates; LANES]);
        for k in 1..run.time.len() {
            scorer.push(k, &[run.tau[k] - path[k]; LANES], &[stiffness[k]; LANES]);
        }
        let ll = scorer.finish();
        assert!(ll.iter().all(|v| *v == ll[0]), "lanes disagree");
        ll[0]
    }

    /// The loading branch of each compared sample of `run` (0, 1, …), found
    /// independently of `RunData::reverses`: a new branch where the strain
    /// increment changes sign.
    pub fn branches(run: &RunData) -> Vec<usize> {
        let n = run.compared();
        let (mut branch, mut b, mut dir) = (vec![0usize; n], 0usize, 0.0f64);
        for k in 1..=n {
            let dg = run.gamma[k] - run.gamma[k - 1];
            if dg.signum() != dir && dir != 0.0 {
                b += 1;
            }
            dir = dg.signum();
            branch[k - 1] = b;
        }
        branch
    }

    /// The sum of a model's pointwise terms along `path`.
    pub fn pointwise_sum(
        model: &dyn NoiseModel,
        run: &RunData,
        path: &[f64],
        values: NoiseValues,
        g: f64,
    ) -> f64 {
        let stiffness = stiffness_path(run, path, g);
        let p = model.pointwise(run, path, &stiffness, &values, &mut crate::rng::stream(1, &[]));
        assert_eq!(p.log_likelihood.len(), run.compared());
        p.log_likelihood.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_model_names_its_parameters_and_units() {
        assert_eq!(unit_of("sigma_I1.0_200rpm"), Some("Pa"));
        assert_eq!(unit_of("rho_a"), Some("1"));
        assert_eq!(unit_of("G"), None);
        for kind in NoiseKind::ALL {
            let m = kind.model(&NoiseOptions::default());
            assert!(
                !m.parameters().is_empty() && m.parameters().len() <= MAX_PARAMETERS,
                "{kind:?}"
            );
        }
    }

    /// Every model, with and without errors in variables, at its profile
    /// fit and at a point away from it: the scorer's log-likelihood plus
    /// the constant it declares equals the sum of its pointwise terms,
    /// whose constants are written out (what the evidence rests on).
    #[test]
    fn every_model_declares_the_constant_its_scorer_leaves_out() {
        use testing::{pointwise_sum, run, scored};
        for eiv in [false, true] {
            let (run, path) = run(if eiv { 1e-8 } else { 0.0 });
            let residuals: Vec<f64> = (1..run.time.len()).map(|k| run.tau[k] - path[k]).collect();
            let options = NoiseOptions { errors_in_variables: eiv, ..NoiseOptions::default() };
            for kind in NoiseKind::ALL {
                let m = kind.model(&options);
                let fitted = m.profile(&run, &residuals, 5e6).coordinates;
                let mut away = fitted;
                for (c, p) in away.iter_mut().zip(m.parameters()) {
                    *c += if p.transform == Transform::Log { 0.3 } else { -0.2 };
                }
                for c in [fitted, away] {
                    let values: Vec<f64> = m
                        .parameters()
                        .iter()
                        .zip(c)
                        .map(|(p, v)| p.transform.to_si(v))
                        .chain(std::iter::repeat(0.0))
                        .take(MAX_PARAMETERS)
                        .collect();
                    let values: NoiseValues = values.try_into().unwrap();
                    let total = pointwise_sum(m.as_ref(), &run, &path, values, 5e6);
                    let with =
                        scored(m.as_ref(), &run, &path, c, 5e6) + m.log_likelihood_constant(&run);
                    assert!(
                        (total - with).abs() < 1e-8 * total.abs(),
                        "{kind:?} (errors in variables {eiv}) at {c:?}: pointwise {total}, scorer + constant {with}"
                    );
                }
            }
        }
    }

    /// Every model's prior normaliser equals ln ∫ exp(log prior) over its
    /// coordinates, integrated here one coordinate at a time (each prior is
    /// a product of one-dimensional ones) by the midpoint rule over the
    /// support found by scanning.
    #[test]
    fn every_model_prior_normaliser_is_the_integral_of_its_prior() {
        let (run, path) = testing::run(0.0);
        let residuals: Vec<f64> = (1..run.time.len()).map(|k| run.tau[k] - path[k]).collect();
        for kind in NoiseKind::ALL {
            let m = kind.model(&NoiseOptions::default());
            let at = m.profile(&run, &residuals, 5e6).coordinates;
            let p0 = m.log_prior(&run, &at);
            let d = m.parameters().len();
            let mut log_integral = -((d - 1) as f64) * p0;
            for i in 0..d {
                let f = |v: f64| {
                    let mut c = at;
                    c[i] = v;
                    m.log_prior(&run, &c).exp()
                };
                let (lo, hi, steps) = (-40.0, 40.0, 400_000);
                let h = (hi - lo) / steps as f64;
                let sum: f64 = (0..steps).map(|k| f(lo + (k as f64 + 0.5) * h)).sum();
                log_integral += (sum * h).ln();
            }
            let declared = m.log_prior_normaliser(&run);
            assert!(
                (log_integral - declared).abs() < 1e-3,
                "{kind:?}: integrated {log_integral}, declared {declared}"
            );
        }
    }

    #[test]
    fn pooling_takes_the_rms_of_scales_and_the_mean_of_the_rest() {
        assert!((Pool::RootMeanSquare.of(&[3.0, 4.0]) - 12.5f64.sqrt()).abs() < 1e-15);
        assert_eq!(Pool::Mean.of(&[0.2, 0.6]), 0.4);
        assert_eq!(Pool::Mean.of(&[]), 0.0);
    }
}
