//! Ctrl-C and SIGTERM: the first asks the sampler to stop after its current
//! step and save a checkpoint (the run then ends with exit status 130 and a
//! line saying how to resume); the second ends the process at once.

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

/// Exit status of an interrupted run (128 + SIGINT, as shells report it).
pub const EXIT_STATUS: i32 = 130;

/// Installs the handler (once per process; later calls do nothing).
pub fn install() {
    let _ = ctrlc::set_handler(|| {
        if REQUESTED.swap(true, Ordering::SeqCst) {
            eprintln!("\nmrbp: interrupted again: stopping now, without a checkpoint");
            std::process::exit(EXIT_STATUS);
        }
        eprintln!("\nmrbp: interrupt: stopping after this step and saving a checkpoint (again to stop at once)");
    });
}

/// Whether a stop has been asked for.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}
