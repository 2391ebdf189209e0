//! `motm-zenoh`: the zenoh bridge as a process ([`motm_zenoh::service`]). It forwards the
//! topics of a bridge config file, or those of tasks that run on another host
//! (`--remote-task perception --side stack|remote`), between this host's iceoryx2 stack
//! (`$MOTM_IPC_PREFIX`) and zenoh.

fn main() -> std::process::ExitCode {
    motm_zenoh::service::main()
}
