//! `fake-panda`: a fake Franka Panda and Franka Hand on loopback that speak the real FCI and
//! Hand protocols ([`motm_fake_panda::service`]).

fn main() -> std::process::ExitCode {
    motm_fake_panda::service::main()
}
