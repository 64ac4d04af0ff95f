//! Acceptance of the independence proposals on Gaussians of 11, 22 and 33
//! coordinates (condition number 1e3, a fixed rotation), walkers started
//! from exact draws, 6 walkers per coordinate: the independence move (its
//! fit to the complementary half degrades with the dimension), the history
//! move, and the anchored move with an exact reference and with a poor one
//! (each variance off by a factor 2 or 1/2 in turn, the mean one sd off).
//! `cargo run --release --example independence_acceptance`.
use mrbp::sampler::{Elliptical, LogDensity, Moments, Move, RunControl, Sampler, SamplerSettings};
use nalgebra::{DMatrix, DVector};
use rand::RngExt;

/// N(0, L Lᵀ), by its lower Cholesky factor L: ln p = −½ |L⁻¹ x|².
struct CholeskyGaussian(DMatrix<f64>);

impl LogDensity for CholeskyGaussian {
    fn dim(&self) -> usize {
        self.0.nrows()
    }
    fn log_density(&self, x: &[f64]) -> f64 {
        self.0
            .solve_lower_triangular(&DVector::from_column_slice(x))
            .map_or(f64::NEG_INFINITY, |z| -0.5 * z.norm_squared())
    }
}

fn main() {
    println!("coordinates | move | reference | acceptance (steps 65-100) | tau_max");
    for d in [11usize, 22, 33] {
        let mut rng = mrbp::rng::stream(5, &[d as u64]);
        let a = DMatrix::from_fn(d, d, |_, _| rng.random::<f64>() - 0.5);
        let q = a.qr().q();
        let lambda = DVector::from_fn(d, |i, _| 10f64.powf(3.0 * i as f64 / (d - 1) as f64));
        let cov = &q * DMatrix::from_diagonal(&lambda) * q.transpose();
        let factor = cov.clone().cholesky().expect("positive definite").l();
        let target = CholeskyGaussian(factor.clone());
        let exact = Elliptical::new(Moments { mean: DVector::zeros(d), cov: cov.clone() })
            .expect("positive definite");
        let scale = DVector::from_fn(d, |i, _| 2f64.powi(i as i32 % 3 - 1).sqrt());
        let poor = Elliptical::new(Moments {
            mean: &factor * DVector::from_element(d, 1.0 / (d as f64).sqrt()),
            cov: DMatrix::from_diagonal(&scale) * &cov * DMatrix::from_diagonal(&scale),
        })
        .expect("positive definite");
        let walkers = 6 * d + (6 * d) % 2;
        let normal = |rng: &mut rand_chacha::ChaCha8Rng| {
            let (u, v): (f64, f64) = (rng.random(), rng.random());
            (-2.0 * u.max(1e-300).ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        let start: Vec<Vec<f64>> = (0..4 * walkers)
            .map(|_| (&factor * DVector::from_fn(d, |_, _| normal(&mut rng))).as_slice().to_vec())
            .collect();
        let cases = [
            ("independence", Move::independence(), None),
            ("history", Move::history(), None),
            ("anchored", Move::anchored(), Some(("exact", exact))),
            ("anchored", Move::anchored(), Some(("poor", poor))),
        ];
        for (name, first, reference) in cases {
            let settings = SamplerSettings {
                walkers,
                ensembles: 4,
                moves: vec![(first, 0.9), (Move::differential_evolution(), 0.1)],
                seed: 3,
            };
            let mut sampler = Sampler::new(&target, settings, &start).expect("a valid start");
            let label = reference.as_ref().map_or("-", |r| r.0);
            if let Some((_, r)) = reference {
                sampler = sampler.with_reference(r);
            }
            sampler.run(&RunControl::fixed(100), &mut []).expect("runs");
            // steps 65-100: after the history move's fit at step 64
            let accepted =
                sampler.chains.accepted.iter().skip(65 * 4 * walkers).filter(|a| **a).count();
            println!(
                "{d} | {name} | {label} | {:.3} | {:.1}",
                accepted as f64 / (36 * 4 * walkers) as f64,
                sampler.diagnostics().tau_max
            );
        }
    }
}
