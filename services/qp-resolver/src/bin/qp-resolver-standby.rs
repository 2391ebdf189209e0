//! `qp-resolver-standby`: the hot-standby redundancy-resolution QP process.

fn main() -> std::process::ExitCode {
    motm_qp_resolver::run(
        &motm_graph::QP_RESOLVER_STANDBY,
        motm_tasks::controllers::STANDBY_RESOLVER_ID,
    )
}
