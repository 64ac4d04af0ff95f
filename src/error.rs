//! One error type for the whole toolkit, and how it maps to exit status.
//!
//! Bad input (a file, a manifest, a command line) is the user's to fix and exits
//! with status 2; everything else exits with 1. Messages are one line and name
//! the file, and where it applies the row and the column.

use std::path::{Path, PathBuf};

pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Something wrong with an input file: missing, unreadable, malformed.
    #[error("{}{}{}: {message}", .file.display(), row_text(.row), column_text(.column))]
    Input { file: PathBuf, row: Option<usize>, column: Option<String>, message: String },
    /// A command line that does not make sense (an option out of range, …).
    #[error("{0}")]
    Usage(String),
    /// A computation that could not be done (a solver that failed, …).
    #[error("{0}")]
    Compute(String),
    /// Writing output failed.
    #[error("{}: {message}", .path.display())]
    Output { path: PathBuf, message: String },
    /// Stopped by Ctrl-C or SIGTERM after saving what can be resumed.
    #[error("{0}")]
    Interrupted(String),
    /// A folder another process is writing: try again when it has ended.
    #[error("{0}")]
    Busy(String),
}

fn row_text(row: &Option<usize>) -> String {
    row.map(|r| format!(", row {r}")).unwrap_or_default()
}

fn column_text(column: &Option<String>) -> String {
    column.as_ref().map(|c| format!(", column '{c}'")).unwrap_or_default()
}

impl Error {
    /// An input error about a whole file.
    pub fn input(file: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Error::Input {
            file: file.as_ref().to_path_buf(),
            row: None,
            column: None,
            message: message.into(),
        }
    }

    /// An input error at one cell of a table (row counted from 1, header excluded).
    pub fn input_at(
        file: impl AsRef<Path>,
        row: Option<usize>,
        column: Option<&str>,
        message: impl Into<String>,
    ) -> Self {
        Error::Input {
            file: file.as_ref().to_path_buf(),
            row,
            column: column.map(str::to_string),
            message: message.into(),
        }
    }

    pub fn output(path: impl AsRef<Path>, message: impl std::fmt::Display) -> Self {
        Error::Output { path: path.as_ref().to_path_buf(), message: message.to_string() }
    }

    /// Exit status of the command line: 2 for bad input or usage and for a
    /// folder another process is writing, 130 when interrupted, 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Input { .. } | Error::Usage(_) | Error::Busy(_) => 2,
            Error::Compute(_) | Error::Output { .. } => 1,
            Error::Interrupted(_) => crate::interrupt::EXIT_STATUS,
        }
    }
}

thread_local! {
    static GUARDED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f`, turning a panic inside it into `None`: for third-party readers
/// of user files (a damaged Parquet file can make its decoder panic), whose
/// failure is a bad input, not a crash. While `f` runs, the panic hook of
/// [`install_panic_hook`] stays silent.
pub fn guard_foreign<T>(f: impl FnOnce() -> T) -> Option<T> {
    GUARDED.with(|g| g.set(true));
    let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).ok();
    GUARDED.with(|g| g.set(false));
    out
}

/// A panic hook that keeps quiet about panics [`guard_foreign`] catches and
/// otherwise reports the panic as an internal error.
pub fn install_panic_hook() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !GUARDED.with(|g| g.get()) {
            eprintln!("mrbp: internal error (please report it with the command and input):");
            default(info);
        }
    }));
}

/// A message on one line: its whitespace runs as single spaces.
pub fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}
