//! `supervisor`: starts, watches and restarts the processes of a stack config, and runs the
//! mission task ([`motm_supervisor::service`]).

fn main() -> std::process::ExitCode {
    motm_supervisor::service::main()
}
