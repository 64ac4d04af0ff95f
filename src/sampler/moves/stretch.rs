//! Goodman & Weare's stretch move.

use rand::RngExt;

use super::point;

/// y = x_j + z (x − x_j) with z ∝ 1/√z on [1/a, a]; factor z^(d−1).
pub fn propose(a: f64, x: &[f64], others: &[f64], rng: &mut impl rand::Rng, y: &mut [f64]) -> f64 {
    let d = x.len();
    let u: f64 = rng.random();
    let z = ((a - 1.0) * u + 1.0).powi(2) / a;
    let xj = point(others, d, rng.random_range(0..others.len() / d));
    for i in 0..d {
        y[i] = xj[i] + z * (x[i] - xj[i]);
    }
    (d as f64 - 1.0) * z.ln()
}

#[cfg(test)]
mod tests {
    #[test]
    fn stretch_factor_stays_in_range() {
        let mut rng = crate::rng::stream(1, &[]);
        let x = [1.0, 2.0];
        let others = [0.0, 0.0, 3.0, 3.0];
        let mut y = [0.0; 2];
        for _ in 0..1000 {
            let f = super::propose(2.0, &x, &others, &mut rng, &mut y);
            let z = f.exp(); // d − 1 = 1
            assert!((0.5..=2.0).contains(&z));
        }
    }
}
