//! mrbp's integration tests, one module a subject, in one test binary:
//! one link of the library and its dependencies instead of one per file,
//! and one pool of test threads for all of them (a long test no longer
//! leaves the other core idle while its file's other tests have finished).
//!
//! Tiers: `cargo test --release` runs the fast tier; the slow tier's tests
//! carry `#[ignore = "slow tier: …"]` and run with
//! `cargo test --release -- --include-ignored` (CI runs both). One subject
//! alone: `cargo test --release --test it sampler::`.

mod common;

mod adjusted;
mod architecture;
mod arviz;
mod bad_input;
mod calibration;
mod cli;
mod compare;
mod consistency;
mod folders;
mod identify;
mod interrupt;
mod laws;
mod python;
mod real_data;
mod report;
mod robustness;
mod sampler;
mod simulate;
mod smc;
mod store;
mod study;
mod tempered;
