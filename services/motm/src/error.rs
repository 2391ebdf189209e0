//! How a command fails: bad input (exit code 2) or a failed run (exit code 1).

/// Exit code for bad input: a bad file, key, value or name.
pub const EXIT_BAD_INPUT: u8 = 2;

/// Exit code for a run that worked but whose task failed, or that failed at run time.
pub const EXIT_FAILED: u8 = 1;

/// Why a command failed; decides the exit code.
#[derive(Debug)]
pub enum CliError {
    /// Bad input: a bad file, key, value or name (exit code 2). Nothing was run.
    BadInput(String),
    /// The command ran but failed (exit code 1).
    Failed(String),
}

impl CliError {
    /// The process exit code for this error.
    pub fn exit_code(&self) -> u8 {
        match self {
            CliError::BadInput(_) => EXIT_BAD_INPUT,
            CliError::Failed(_) => EXIT_FAILED,
        }
    }
}

impl std::fmt::Display for CliError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CliError::BadInput(m) | CliError::Failed(m) => f.write_str(m),
        }
    }
}
