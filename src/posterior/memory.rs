//! The curvature adjustment of the likelihood for the memory of its
//! residuals ([`super::Memory::Adjusted`]; docs/calibration.md, "The
//! adjusted likelihood").
//!
//! At the MAP of the independent likelihood's surrogate, with J the
//! Jacobian of the whitened residuals (in the sampler's θ coordinates x, in
//! which the likelihood is close to Gaussian; the model terms beside),
//! the likelihood's curvature is H = JᵀJ while its score −Jᵀe has
//! covariance V = Σ_runs J_rᵀ R_r J_r, R_r the correlation matrix of run
//! r's whitened residuals (Toeplitz, from their autocorrelation about zero
//! out to Geyer's initial positive sequence). With memory, V exceeds H and
//! the sandwich H⁻¹VH⁻¹ is θ's covariance; the likelihood evaluated at
//! x* = c + C (x − c), c the independent posterior's mode, has
//! curvature CᵀHC, which C = H^(−½) D^(−½) H^(½), D = H^(−½) V H^(−½),
//! makes H V⁻¹ H (Chandler & Bate 2007; Ribatet, Cooley & Davison 2012).
//! D's eigenvalues are the variance inflation of each direction: the
//! residuals' integrated autocorrelation time k for every direction when J
//! is constant in time (a location), so the tempered likelihood is the
//! special case where every direction is informed alike. They are kept at
//! 1 or more: the adjustment only widens.

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use super::map::{whitened_residuals, MapEstimate};
use super::{MemoryAdjustment, Posterior};

/// The smallest eigenvalue of the likelihood's curvature kept, relative to
/// its largest: a direction the records do not inform is not adjusted.
const FLAT: f64 = 1e-12;

/// The adjustment measured at the MAP `map` of the independent likelihood
/// of `post` (its Jacobian and residuals), centred on `centre`, the mode
/// of the independent posterior (sampler coordinates): the surrogate's
/// optimum is not the likelihood's where the noise depends on θ (errors in
/// variables), and the adjusted likelihood's peak lies C⁻¹ times as far
/// from the centre as the likelihood's own. `None` where the residuals
/// cannot be integrated or the model terms' curvature is singular.
pub fn adjustment(post: &Posterior, map: &MapEstimate, centre: &[f64]) -> Option<MemoryAdjustment> {
    let l = &post.layout;
    let (nt, nf) = (l.theta.len(), l.fitted.len());
    // θ first, then the model terms
    if l.theta.start != 0 {
        return None;
    }
    let white = whitened_residuals(post, map)?;
    let rows: usize = white.iter().map(Vec::len).sum();
    let jac = map.jacobian();
    if jac.nrows() < rows || jac.ncols() != nf {
        return None;
    }
    let j = jac.rows(0, rows).into_owned();
    // H = JᵀJ (the terms' priors keep their block determined)
    let mut hess = j.transpose() * &j;
    for k in l.spring.clone() {
        hess[(k, k)] += post.terms.gas_spring_sd_n_per_m.powi(-2);
    }
    for k in l.offset.clone() {
        hess[(k, k)] += post.terms.force_offset_sd_n.powi(-2);
    }
    // V = Σ_r J_rᵀ R_r J_r: each row convolved with the run's correlations
    let mut v = DMatrix::<f64>::zeros(nf, nf);
    let mut from = 0;
    for w in &white {
        let n = w.len();
        let (rho, window) = correlations(w);
        let jr = j.rows(from, n);
        let flat: Vec<f64> =
            (0..n).flat_map(|t| jr.row(t).iter().copied().collect::<Vec<_>>()).collect();
        let mut k = DMatrix::<f64>::zeros(n, nf);
        let mut row = vec![0.0; nf];
        for t in 0..n {
            row.iter_mut().for_each(|v| *v = 0.0);
            for s in t.saturating_sub(window)..=(t + window).min(n - 1) {
                let r = rho[t.abs_diff(s)];
                for (acc, x) in row.iter_mut().zip(&flat[s * nf..(s + 1) * nf]) {
                    *acc += r * x;
                }
            }
            for (c, value) in row.iter().enumerate() {
                k[(t, c)] = *value;
            }
        }
        v += jr.transpose() * k;
        from += n;
    }
    // θ's information and score with the terms profiled out
    let (h_tt, v_tt) =
        (hess.view((0, 0), (nt, nt)).into_owned(), v.view((0, 0), (nt, nt)).into_owned());
    let (h_eff, v_eff) = if nf > nt {
        let h_ff = hess.view((nt, nt), (nf - nt, nf - nt)).into_owned();
        let b_tail = -(hess.view((0, nt), (nt, nf - nt)) * h_ff.try_inverse()?);
        let mut b = DMatrix::<f64>::zeros(nt, nf);
        b.view_mut((0, 0), (nt, nt)).fill_with_identity();
        b.view_mut((0, nt), (nt, nf - nt)).copy_from(&b_tail);
        (&b * &hess * b.transpose(), &b * &v * b.transpose())
    } else {
        (h_tt, v_tt)
    };
    let (root, inverse_root) = roots(&h_eff)?;
    let d = symmetric(&inverse_root * v_eff * &inverse_root);
    let eigen = SymmetricEigen::new(d);
    let samples = rows as f64;
    let inflation: Vec<f64> = eigen.eigenvalues.iter().map(|v| v.clamp(1.0, samples)).collect();
    let d_inverse_root = &eigen.eigenvectors
        * DMatrix::from_diagonal(&DVector::from_iterator(
            nt,
            inflation.iter().map(|v| v.powf(-0.5)),
        ))
        * eigen.eigenvectors.transpose();
    let c = inverse_root * d_inverse_root * root;
    let mut sorted = inflation;
    sorted.sort_by(|a, b| b.total_cmp(a));
    Some(MemoryAdjustment {
        runs: post.runs.iter().map(|r| r.id.clone()).collect(),
        coordinates: l.theta_names().to_vec(),
        reference_work_pa: l.reference_work(),
        centre: centre[..nt].to_vec(),
        matrix: (0..nt).map(|i| c.row(i).iter().copied().collect()).collect(),
        inflation: sorted,
    })
}

/// The autocorrelations ρ_0 = 1, ρ_1, … of whitened residuals `w` about
/// zero (not about their mean: a misfit the whole record shares is memory
/// too), out to Geyer's (1992) initial positive sequence: the lags before
/// the first pair ρ_2m + ρ_2m+1 that is not positive, at most half the
/// record. And that window, the last lag summed.
fn correlations(w: &[f64]) -> (Vec<f64>, usize) {
    let n = w.len();
    let c0: f64 = w.iter().map(|v| v * v).sum();
    let at = |l: usize| {
        if c0 > 0.0 {
            w[..n - l].iter().zip(&w[l..]).map(|(a, b)| a * b).sum::<f64>() / c0
        } else {
            0.0
        }
    };
    // the pair (ρ_0, ρ_1) first, then pairs while their sum is positive
    let mut rho = vec![1.0, if n > 1 { at(1) } else { 0.0 }];
    while rho.len() + 2 <= n / 2 {
        let (a, b) = (at(rho.len()), at(rho.len() + 1));
        if a + b <= 0.0 {
            break;
        }
        rho.extend([a, b]);
    }
    let window = rho.len() - 1;
    (rho, window)
}

fn symmetric(m: DMatrix<f64>) -> DMatrix<f64> {
    (&m + m.transpose()) * 0.5
}

/// H^(½) and H^(−½) of a symmetric positive semi-definite `h`, its
/// eigenvalues floored at [`FLAT`] of the largest.
fn roots(h: &DMatrix<f64>) -> Option<(DMatrix<f64>, DMatrix<f64>)> {
    let eigen = SymmetricEigen::new(symmetric(h.clone()));
    let top = eigen.eigenvalues.max();
    if !(top > 0.0 && top.is_finite()) {
        return None;
    }
    let values = eigen.eigenvalues.map(|v| v.max(FLAT * top));
    let q = &eigen.eigenvectors;
    let root = q * DMatrix::from_diagonal(&values.map(f64::sqrt)) * q.transpose();
    let inverse_root = q * DMatrix::from_diagonal(&values.map(|v| 1.0 / v.sqrt())) * q.transpose();
    Some((root, inverse_root))
}
