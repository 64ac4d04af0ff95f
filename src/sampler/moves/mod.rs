//! Ensemble proposals, one move a file. Each takes the walker's position and
//! the positions of the complementary half of its ensemble (fixed while this
//! half moves, which keeps every move exact), writes the proposal and
//! returns the log of its Metropolis-Hastings correction factor.

mod anchored;
pub mod curved;
mod differential_evolution;
mod independence;
pub mod mixture;
mod snooker;
mod stretch;

pub use mixture::Mixture;

use super::elliptical::Elliptical;

use serde::{Deserialize, Serialize};

/// A proposal move of the ensemble sampler.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Move {
    /// Goodman & Weare's stretch move: y = x_j + z (x − x_j), z ∝ 1/√z on
    /// [1/a, a]; factor z^(d−1).
    Stretch { a: f64 },
    /// Differential evolution (ter Braak 2006): y = x + γ (x_j − x_k), with
    /// γ = γ₀ (1 + σ ε), ε ~ N(0, 1), γ₀ = 2.38/√(2d) unless given.
    DifferentialEvolution { gamma0: Option<f64>, sigma: f64 },
    /// DE snooker (ter Braak & Vrugt 2008): a jump along the line through x
    /// and a third walker z; factor (|y − z| / |x − z|)^(d−1).
    Snooker { gamma: f64 },
    /// Independence proposal from a multivariate Student-t (`df` degrees of
    /// freedom; Gaussian without) with the mean and covariance of the
    /// complementary half, the covariance scaled by `scale`²; factor
    /// q(x)/q(y). On a posterior close to Gaussian it proposes nearly
    /// independent draws.
    Independence { df: Option<f64>, scale: f64 },
    /// Independence proposal from a Student-t mixture (`df`; Gaussian
    /// without) fitted to the ensemble's own positions over the second half
    /// of its steps, refitted at steps 8, 16, 32, …, 1024 and fixed in
    /// between and after, blended with the complementary half's fit
    /// ([`mixture`]); factor q(x)/q(y). Before the first fit,
    /// [`Move::Independence`].
    History { df: Option<f64> },
    /// The independence proposal anchored on a fixed reference (the
    /// calibration's Laplace approximation at the mode): a Student-t
    /// (`df`; Gaussian without) with the complementary half's moments taken
    /// in the reference's whitened coordinates, its covariance shrunk toward
    /// its mean variance times the identity (one Ledoit–Wolf weight) and its
    /// mean toward the reference's (positive-part James–Stein)
    /// ([`anchored`]); factor q(x)/q(y). Without a reference, or where the
    /// half lies far from it, [`Move::Independence`] with scale 1.
    Anchored { df: Option<f64> },
    /// An independence proposal that follows a curved ridge: an equal
    /// mixture of a *tube* fitted to the complementary half (one coordinate
    /// along the ridge, drawn from a kernel density; the others across it,
    /// Student-t about a quadratic curve with a width that varies along
    /// it), the half's own Student-t, and the anchored fit where the
    /// reference is near ([`curved`]); factor q(x)/q(y). Once the
    /// ensemble has a history (steps 8, 16, 32, …, 1024, as
    /// [`Move::History`]), a tube fitted to it (a cubic curve) proposes
    /// too, blended with the half's fit.
    Curved { df: Option<f64> },
}

impl Default for Move {
    fn default() -> Self {
        Move::Stretch { a: 2.0 }
    }
}

impl Move {
    pub fn differential_evolution() -> Self {
        Move::DifferentialEvolution { gamma0: None, sigma: 1.0e-5 }
    }

    pub fn snooker() -> Self {
        Move::Snooker { gamma: 1.7 }
    }

    pub fn independence() -> Self {
        Move::Independence { df: Some(10.0), scale: 1.0 }
    }

    pub fn history() -> Self {
        Move::History { df: Some(10.0) }
    }

    pub fn anchored() -> Self {
        Move::Anchored { df: Some(10.0) }
    }

    pub fn curved() -> Self {
        Move::Curved { df: Some(10.0) }
    }

    /// Smallest complementary half the move can work with.
    pub fn min_complement(&self) -> usize {
        match self {
            Move::Stretch { .. } => 1,
            Move::DifferentialEvolution { .. }
            | Move::Independence { .. }
            | Move::History { .. }
            | Move::Anchored { .. }
            | Move::Curved { .. } => 2,
            Move::Snooker { .. } => 3,
        }
    }

    pub fn check(&self) -> Result<(), String> {
        match *self {
            Move::Stretch { a } if !(a > 1.0) => {
                Err(format!("stretch scale a = {a} must exceed 1"))
            }
            Move::DifferentialEvolution { gamma0: Some(g), .. } if !(g > 0.0) => {
                Err(format!("DE gamma0 = {g} must be positive"))
            }
            Move::DifferentialEvolution { sigma, .. } if !(sigma >= 0.0) => {
                Err(format!("DE sigma = {sigma} must be non-negative"))
            }
            Move::Snooker { gamma } if !(gamma > 0.0) => {
                Err(format!("snooker gamma = {gamma} must be positive"))
            }
            Move::Independence { df: Some(df), .. }
            | Move::History { df: Some(df) }
            | Move::Anchored { df: Some(df) }
            | Move::Curved { df: Some(df) }
                if !(df > 0.0) =>
            {
                Err(format!("independence df = {df} must be positive"))
            }
            Move::Independence { scale, .. } if !(scale > 0.0 && scale.is_finite()) => {
                Err(format!("independence scale = {scale} must be positive"))
            }
            _ => Ok(()),
        }
    }

    /// Whether the move proposes from a fit to the ensemble's history.
    pub fn uses_history(&self) -> bool {
        matches!(self, Move::History { .. } | Move::Curved { .. })
    }

    /// The degrees of freedom of an independence proposal's Student-t
    /// (`None`: Gaussian, or a move that has none).
    fn df(&self) -> Option<f64> {
        match *self {
            Move::Independence { df, .. }
            | Move::History { df }
            | Move::Anchored { df }
            | Move::Curved { df } => df,
            _ => None,
        }
    }

    /// The scale of an independence proposal's covariance (1 but for
    /// [`Move::Independence`]).
    fn scale(&self) -> f64 {
        match *self {
            Move::Independence { scale, .. } => scale,
            _ => 1.0,
        }
    }

    /// What the move fits to the complementary half `others` of an
    /// ensemble (points of `d` coordinates one after another), given the
    /// fits to the ensemble's history (none before the first fit), and the
    /// sampler's fixed reference distribution, if it has one: done once
    /// per ensemble and half-step, before its walkers propose.
    pub fn fit<'h>(
        &self,
        others: &[f64],
        d: usize,
        history: &'h Learned,
        reference: Option<&Elliptical>,
    ) -> Fit<'h> {
        let own = || Fit::Single(independence::fitted(others, d));
        match *self {
            Move::Stretch { .. } | Move::DifferentialEvolution { .. } | Move::Snooker { .. } => {
                Fit::Points
            }
            Move::Independence { .. } => own(),
            Move::Anchored { .. } => reference
                .and_then(|r| anchored::anchored_fit(others, d, r))
                .map_or_else(own, |fit| Fit::Single(Some(fit))),
            Move::History { .. } => history
                .mixture
                .as_ref()
                .map_or_else(own, |h| Fit::History(h, Mixture::of_points(others, d))),
            Move::Curved { .. } => Fit::Curved(
                curved::Proposal::fit(others, d, reference).map(Box::new),
                history.tube.as_ref(),
            ),
        }
    }

    /// Writes the proposal for walker position `x` into `y`, with the other
    /// half of the ensemble `others` and what the move fitted to it
    /// ([`Move::fit`]); returns ln of the proposal's correction factor.
    pub fn propose(
        &self,
        fit: &Fit,
        x: &[f64],
        others: &[f64],
        rng: &mut impl rand::Rng,
        y: &mut [f64],
    ) -> f64 {
        match (*self, fit) {
            (Move::Stretch { a }, _) => stretch::propose(a, x, others, rng, y),
            (Move::DifferentialEvolution { gamma0, sigma }, _) => {
                differential_evolution::propose(gamma0, sigma, x, others, rng, y)
            }
            (Move::Snooker { gamma }, _) => snooker::propose(gamma, x, others, rng, y),
            (_, Fit::Single(f)) => {
                independence::propose(self.df(), self.scale(), f.as_ref(), x, rng, y)
            }
            (_, Fit::History(h, current)) => {
                mixture::propose(*h, current.as_ref(), self.df(), x, rng, y)
            }
            (_, Fit::Curved(q, Some(tube))) => {
                mixture::propose(*tube, q.as_deref(), self.df(), x, rng, y)
            }
            (_, Fit::Curved(Some(q), None)) => q.propose(self.df(), x, rng, y),
            (_, Fit::Curved(None, None)) => {
                y.copy_from_slice(x);
                0.0
            }
            // an independence move given no fit fits the half itself
            (_, Fit::Points) => independence::propose(
                self.df(),
                self.scale(),
                independence::fitted(others, x.len()).as_ref(),
                x,
                rng,
                y,
            ),
        }
    }
}

/// A proposal that draws independently of the walker's position: the
/// independence-type moves' fits (a mixture, a tube, the curved mixture).
pub trait Independent {
    /// A draw into `y`, Student-t parts with `df` degrees of freedom
    /// (Gaussian without).
    fn draw(&self, df: Option<f64>, rng: &mut impl rand::Rng, y: &mut [f64]);

    /// ln q(v), up to a constant shared with every proposal of the same
    /// kind (normalised where kinds are mixed).
    fn log_q(&self, df: Option<f64>, v: &[f64]) -> f64;

    /// y drawn from the proposal; the independence factor q(x)/q(y).
    fn propose(&self, df: Option<f64>, x: &[f64], rng: &mut impl rand::Rng, y: &mut [f64]) -> f64 {
        self.draw(df, rng, y);
        self.log_q(df, x) - self.log_q(df, y)
    }
}

/// What a move fitted to the complementary half of an ensemble
/// ([`Move::fit`]).
#[derive(Clone, Debug)]
pub enum Fit<'h> {
    /// Nothing: the move uses the half's points themselves.
    Points,
    /// One Student-t: the half's own, or the anchored move's
    /// ([`anchored::anchored_fit`]) (`None`: a degenerate half, the walker
    /// stays).
    Single(Option<Elliptical>),
    /// The history's mixture and the half's own fit.
    History(&'h Mixture, Option<Mixture>),
    /// The curved move's mixture (`None`: a degenerate half) and the tube
    /// of the ensemble's history, if fitted (neither: the walker stays).
    Curved(Option<Box<curved::Proposal>>, Option<&'h curved::Tube>),
}

/// What an ensemble learned from its own history at the last fit step
/// ([`mixture::last_fit_step`]), for the moves that use it: the mixture of
/// [`Move::History`], the tube of [`Move::Curved`].
#[derive(Clone, Debug, Default)]
pub struct Learned {
    pub mixture: Option<Mixture>,
    pub tube: Option<curved::Tube>,
}

impl Learned {
    /// The fits that `moves` use, to the walkers' positions `walkers` (per
    /// walker, points of `d` coordinates in time order); the mixture's EM
    /// starts drawn from `rng`.
    pub fn fit(
        moves: &[(Move, f64)],
        walkers: &[Vec<f64>],
        d: usize,
        rng: &mut impl rand::Rng,
    ) -> Learned {
        let uses = |f: fn(&Move) -> bool| moves.iter().any(|(m, _)| f(m));
        Learned {
            mixture: if uses(|m| matches!(m, Move::History { .. })) {
                Mixture::fit(walkers, d, rng)
            } else {
                None
            },
            tube: if uses(|m| matches!(m, Move::Curved { .. })) {
                curved::Tube::of_history(walkers, d)
            } else {
                None
            },
        }
    }
}

/// The `j`-th of the points stored one after another in `points`.
fn point(points: &[f64], d: usize, j: usize) -> &[f64] {
    &points[j * d..(j + 1) * d]
}

/// Two distinct indices below `n`, uniformly.
fn distinct_pair(rng: &mut impl rand::Rng, n: usize) -> (usize, usize) {
    use rand::RngExt;
    let j = rng.random_range(0..n);
    let mut k = rng.random_range(0..n - 1);
    if k >= j {
        k += 1;
    }
    (j, k)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distinct_pairs_are_distinct() {
        let mut rng = crate::rng::stream(2, &[]);
        for _ in 0..1000 {
            let (j, k) = distinct_pair(&mut rng, 3);
            assert!(j != k && j < 3 && k < 3);
        }
    }
}
