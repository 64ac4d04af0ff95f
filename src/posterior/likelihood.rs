//! The likelihood of one run: the records as the model sees them, the
//! residuals' sufficient statistics, and the noise models that score them.

use serde::{Deserialize, Serialize};
use statrs::function::gamma::ln_gamma;

use crate::data::{noise_variance, smoothed_strain, Run};
use crate::data::smooth::centre_weight;

/// The residual model of the force record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseModel {
    /// Independent Gaussian residuals, one unknown σ per run.
    #[serde(alias = "Gaussian")]
    Gaussian,
    /// Independent Student-t residuals (fixed ν), one unknown scale per run:
    /// robust to outliers.
    #[serde(alias = "StudentT")]
    StudentT,
    /// AR(1) residuals, one unknown innovation σ and lag-one correlation ρ
    /// per run: for dense records whose residuals are correlated, where an
    /// independent model claims far too much certainty.
    #[serde(alias = "Ar1")]
    Ar1,
}

/// Which samples of each record enter the likelihood.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum RecordPart {
    /// The first loading branch (the paper's choice).
    #[serde(alias = "FirstBranch")]
    FirstBranch,
    /// From the start to the last reversal: every complete branch.
    #[serde(alias = "AllBranches")]
    AllBranches,
    /// Every sample.
    #[serde(alias = "WholeRecord")]
    WholeRecord,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LikelihoodSettings {
    pub noise: NoiseModel,
    /// Half-width (ms) of the local cubic fit that smooths the measured
    /// strain before it drives the model, at least [`crate::data::smooth::MIN_SMOOTH_SAMPLES`]
    /// samples; 0 uses the raw samples. The model turns displacement noise
    /// (and the quantisation of a digital displacement channel) into stress
    /// noise G δγ and biases G (an errors-in-variables effect); a stand's
    /// displacement is smooth on this scale, so the fit removes noise, not
    /// signal.
    pub smooth_strain_ms: f64,
    /// Degrees of freedom of the Student-t model.
    pub student_nu: f64,
    pub part: RecordPart,
    /// Errors in variables (Gaussian noise): the measured strain is noisy
    /// too, and its noise reaches the stress through the model's tangent
    /// stiffness S_k = dτ/dγ along the path (G when elastic, near 0 in
    /// flow). Each residual then has variance σ² + S_k² s_γ², with s_γ² the
    /// strain noise estimated from the record, and the error of the strain
    /// at each reversal, which the whole branch after it shares, as one
    /// random offset per branch (docs/calibration.md). On by default; it
    /// applies with Gaussian noise only.
    pub errors_in_variables: bool,
}

impl Default for LikelihoodSettings {
    fn default() -> Self {
        LikelihoodSettings {
            noise: NoiseModel::Gaussian,
            smooth_strain_ms: 2.0,
            student_nu: 5.0,
            part: RecordPart::WholeRecord,
            errors_in_variables: true,
        }
    }
}

impl LikelihoodSettings {
    pub fn check(&self) -> Result<(), String> {
        if !(self.smooth_strain_ms >= 0.0) {
            return Err("smooth_strain_ms must be 0 or positive".into());
        }
        if self.noise == NoiseModel::StudentT && !(self.student_nu > 0.0) {
            return Err("student_nu must be positive".into());
        }
        Ok(())
    }

    /// Whether the errors-in-variables terms apply: asked for, and with
    /// Gaussian noise (the other noise models take the strain as exact).
    pub fn eiv(&self) -> bool {
        self.errors_in_variables && self.noise == NoiseModel::Gaussian
    }
}


/// One run as the likelihood sees it.
#[derive(Clone, Debug)]
pub struct RunData {
    pub id: String,
    pub time: Vec<f64>,
    /// The strain that drives the model (smoothed).
    pub gamma: Vec<f64>,
    pub tau: Vec<f64>,
    pub initial_tau: f64,
    pub current_a: f64,
    /// The damper's area and gap, which turn force terms into stress.
    pub area_m2: f64,
    pub gap_m: f64,
    /// Variance of the measured strain's noise (displacement noise and
    /// quantisation over h²), estimated from the record: what the
    /// errors-in-variables likelihood propagates into stress.
    pub strain_noise_var: f64,
    /// The share of that variance left in the smoothed strain at one sample
    /// (the smoother's centre weight).
    pub strain_smoothing_share: f64,
}

impl RunData {
    /// The samples of `run` that `part` selects (always from the first
    /// sample: the state at any point depends on the whole history before it).
    pub fn from_run(run: &Run, part: RecordPart, smooth_strain_ms: f64) -> RunData {
        let end = match part {
            RecordPart::WholeRecord => run.shear.len(),
            RecordPart::FirstBranch => run.branches[0].end,
            RecordPart::AllBranches => {
                // the end of the last branch that ends at a reversal
                let complete = run.branches.len().saturating_sub(1).max(1);
                run.branches[complete - 1].end
            }
        };
        let sh = &run.shear;
        let gamma = smoothed_strain(&sh.time, &sh.gamma, smooth_strain_ms);
        let strain_smoothing_share = centre_weight(&sh.time, smooth_strain_ms);
        let strain_noise_var = noise_variance(&sh.gamma, &gamma, strain_smoothing_share);
        RunData {
            id: run.id().to_string(),
            time: sh.time[..end].to_vec(),
            gamma: gamma[..end].to_vec(),
            tau: run.shear.tau[..end].to_vec(),
            initial_tau: run.shear.initial_tau,
            current_a: run.spec.current_a,
            area_m2: run.geometry.area_m2,
            gap_m: run.geometry.gap_m,
            strain_noise_var,
            strain_smoothing_share,
        }
    }

    /// Residuals compared: every sample after the first.
    pub fn compared(&self) -> usize {
        self.time.len() - 1
    }

    /// The stress the model terms add at sample `k` (Pa).
    #[inline(always)]
    pub fn terms_stress(&self, k: usize, spring_n_per_m: f64, offset_n: f64) -> f64 {
        super::terms::ModelTerms::stress(offset_n, spring_n_per_m, self.gamma[k], self.area_m2, self.gap_m)
    }
}

/// ½ ln 2π, the constant of a normal log-density.
pub const HALF_LN_2PI: f64 = 0.918_938_533_204_672_7;

/// ln N(r; 0, sd²).
#[inline]
pub fn normal_ln_pdf(r: f64, sd: f64) -> f64 {
    -HALF_LN_2PI - sd.ln() - 0.5 * (r / sd).powi(2)
}

/// ln Γ((ν+1)/2) − ln Γ(ν/2) − ½ ln(νπ), the constant of a Student-t
/// log-density with ν degrees of freedom.
pub fn student_t_log_constant(nu: f64) -> f64 {
    ln_gamma(0.5 * (nu + 1.0)) - ln_gamma(0.5 * nu) - 0.5 * (nu * std::f64::consts::PI).ln()
}

/// The model's tangent stiffness dτ/dγ between two samples (stress change
/// `dtau` over strain change `dgamma`), within [0, G], and G where the
/// strain stands still: what carries the strain's noise into the stress
/// (errors in variables), in the likelihood, the MAP weights and the bands.
#[inline(always)]
pub fn tangent_stiffness(dtau: f64, dgamma: f64, g: f64) -> f64 {
    if dgamma.abs() > 1e-12 {
        (dtau / dgamma).clamp(0.0, g)
    } else {
        g
    }
}

/// Sufficient statistics of the residuals r_k = τ_obs − τ_model of one run,
/// k = 1.. (the first sample is the fixed initial state).
#[derive(Clone, Copy, Debug, Default)]
pub struct ResidualStats {
    pub n: f64,
    /// Σ r_k²
    pub sum_sq: f64,
    /// Σ_{k≥2} r_k r_{k−1}, Σ_{k≥2} r_{k−1}², r_1 (for AR(1))
    pub lag_cross: f64,
    pub lag_sq: f64,
    pub first: f64,
    /// Σ ln(1 + r²/(ν s²)) (Student-t, with the run's scale)
    pub log_t: f64,
    /// Errors in variables: Σ ln(1 + a_k/σ²) and Σ r_k²/(σ² + a_k), with
    /// a_k = S_k² s_γ² the propagated strain noise (σ the lane's).
    pub eiv: Option<(f64, f64)>,
}

impl ResidualStats {
    /// Adds residual `r` at sample `k` (from 1), `prev` the one before it;
    /// `inv_nu_s2` = 1/(ν s²) where Student-t terms are wanted, else `None`.
    #[inline(always)]
    pub fn push(&mut self, k: usize, r: f64, prev: f64, inv_nu_s2: Option<f64>) {
        self.n += 1.0;
        self.sum_sq += r * r;
        if k == 1 {
            self.first = r;
        } else {
            self.lag_cross += r * prev;
            self.lag_sq += prev * prev;
        }
        if let Some(c) = inv_nu_s2 {
            self.log_t += (r * r * c).ln_1p();
        }
    }
}

impl NoiseModel {
    /// Log-likelihood of one run from its residual statistics, its noise
    /// scale (ln σ) and, for AR(1), its ρ; up to the constant −n/2 ln 2π of
    /// the Gaussian models (which does not depend on the parameters).
    pub fn log_likelihood(self, st: &ResidualStats, log_sigma: f64, rho: f64, student_nu: f64) -> f64 {
        let sigma2 = (2.0 * log_sigma).exp();
        match self {
            NoiseModel::Gaussian => match st.eiv {
                Some((log_inflation, weighted_sq)) => -st.n * log_sigma - 0.5 * log_inflation - 0.5 * weighted_sq,
                None => -st.n * log_sigma - 0.5 * st.sum_sq / sigma2,
            },
            NoiseModel::StudentT => {
                let nu = student_nu;
                st.n * student_t_log_constant(nu)
                    - st.n * log_sigma
                    - 0.5 * (nu + 1.0) * st.log_t
            }
            NoiseModel::Ar1 => {
                // r_1 ~ N(0, σ²/(1−ρ²)), r_k − ρ r_{k−1} ~ N(0, σ²)
                let tail_sq = st.sum_sq - st.first * st.first;
                let innov = tail_sq - 2.0 * rho * st.lag_cross + rho * rho * st.lag_sq;
                let one = 1.0 - rho * rho;
                -st.n * log_sigma + 0.5 * one.ln() - 0.5 * (one * st.first * st.first + innov) / sigma2
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};
    use statrs::distribution::{Continuous, StudentsT};

    fn residuals() -> Vec<f64> {
        // a fixed, irregular sequence with some correlation
        (1..=40).map(|k| 300.0 * ((k as f64 * 0.7).sin() + 0.4 * (k as f64 * 2.3).cos())).collect()
    }

    fn stats(r: &[f64], inv_nu_s2: Option<f64>) -> ResidualStats {
        let mut st = ResidualStats::default();
        let mut prev = 0.0;
        for (i, v) in r.iter().enumerate() {
            st.push(i + 1, *v, prev, inv_nu_s2);
            prev = *v;
        }
        st
    }

    /// Gaussian: Σ ln N(r_k; 0, σ²) from statrs-free arithmetic, up to the
    /// constant −n/2 ln 2π.
    #[test]
    fn gaussian_matches_the_sum_of_normal_log_densities() {
        let r = residuals();
        let sigma: f64 = 250.0;
        let direct: f64 = r.iter().map(|v| -sigma.ln() - 0.5 * (v / sigma).powi(2)).sum();
        let ll = NoiseModel::Gaussian.log_likelihood(&stats(&r, None), sigma.ln(), 0.0, 5.0);
        assert!((ll - direct).abs() < 1e-9 * direct.abs(), "{ll} vs {direct}");
    }

    /// Student-t: the sum of statrs' Student-t log-densities with location
    /// 0, scale s and ν degrees of freedom.
    #[test]
    fn student_t_matches_statrs() {
        let r = residuals();
        let (s, nu): (f64, f64) = (180.0, 5.0);
        let t = StudentsT::new(0.0, s, nu).unwrap();
        let direct: f64 = r.iter().map(|v| t.ln_pdf(*v)).sum();
        let ll = NoiseModel::StudentT.log_likelihood(&stats(&r, Some(1.0 / (nu * s * s))), s.ln(), 0.0, nu);
        assert!((ll - direct).abs() < 1e-9 * direct.abs(), "{ll} vs {direct}");
    }

    /// AR(1): the multivariate normal log-density of the whole residual
    /// vector with the stationary covariance σ² ρ^|i−j| / (1 − ρ²), by a
    /// Cholesky factorisation, up to the constant −n/2 ln 2π.
    #[test]
    fn ar1_matches_the_multivariate_normal() {
        let r = residuals();
        let n = r.len();
        let (sigma, rho): (f64, f64) = (220.0, 0.6);
        let cov = DMatrix::from_fn(n, n, |i, j| sigma * sigma * rho.powi((i as i32 - j as i32).abs()) / (1.0 - rho * rho));
        let chol = cov.cholesky().unwrap();
        let x = DVector::from_column_slice(&r);
        let quad = x.dot(&chol.solve(&x));
        let log_det: f64 = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
        let direct = -0.5 * log_det - 0.5 * quad;
        let ll = NoiseModel::Ar1.log_likelihood(&stats(&r, None), sigma.ln(), rho, 5.0);
        assert!((ll - direct).abs() < 1e-9 * direct.abs(), "{ll} vs {direct}");
    }
}
