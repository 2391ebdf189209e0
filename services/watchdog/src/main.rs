//! `watchdog`: raises safe-stop when the control path stalls ([`motm_watchdog::service`]).

fn main() -> std::process::ExitCode {
    motm_watchdog::service::main()
}
