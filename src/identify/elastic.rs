//! The shear modulus G from the initial elastic slope of τ(γ).

/// G as the least-squares slope of τ against γ over the start of a loading
/// branch: from its first sample until τ has covered `share` of its rise to
/// the branch's extreme. Before that point the inelastic rate of eq. 3 is
/// negligible (for the 1 A reference, γ̇ᴵ < 1e-3 1/s below 40 % of the peak),
/// so τ(γ) is a straight line of slope G. Returns (G, samples used).
pub fn elastic_modulus(gamma: &[f64], tau: &[f64], tau_smooth: &[f64], share: f64) -> (f64, usize) {
    let start = tau_smooth[0];
    let peak = tau_smooth.iter().copied().fold(start, |m, v| {
        if (v - start).abs() > (m - start).abs() {
            v
        } else {
            m
        }
    });
    let limit = share * (peak - start).abs();
    let end = tau_smooth
        .iter()
        .position(|v| (v - start).abs() > limit)
        .unwrap_or(tau.len())
        .max(3)
        .min(tau.len());
    (slope(&gamma[..end], &tau[..end]), end)
}

/// Least-squares slope of y on x (with intercept).
pub fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let xm = x.iter().sum::<f64>() / n;
    let ym = y.iter().sum::<f64>() / n;
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - xm) * (b - ym)).sum();
    let sxx: f64 = x.iter().map(|a| (a - xm).powi(2)).sum();
    sxy / sxx
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slope_of_the_initial_straight_part() {
        // elastic up to τ = 30 (G = 10), then a slope of 2 up to τ = 43.8:
        // the share 0.4 of that rise stops the fit below τ = 17.52, i.e. after
        // the 18 samples τ = 0…17, inside the straight part
        let gamma: Vec<f64> = (0..100).map(|i| i as f64 * 0.1).collect();
        let tau: Vec<f64> =
            gamma.iter().map(|g| (10.0 * g).min(30.0 + (g - 3.0).max(0.0) * 2.0)).collect();
        let (g, used) = elastic_modulus(&gamma, &tau, &tau, 0.4);
        assert!((g - 10.0).abs() < 1e-9, "{g}");
        assert_eq!(used, 18);
    }
}
