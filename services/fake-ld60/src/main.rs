//! `fake-ld60`: a fake Omron LD-60 on loopback TCP (ArNetworking, ARCL) whose physics is the
//! simulator's ([`motm_fake_ld60::service`]).

fn main() -> std::process::ExitCode {
    motm_fake_ld60::service::main()
}
