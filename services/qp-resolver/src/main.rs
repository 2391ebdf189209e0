//! `qp-resolver`: the primary redundancy-resolution QP process.

fn main() -> std::process::ExitCode {
    motm_qp_resolver::run(
        &motm_graph::QP_RESOLVER,
        motm_tasks::controllers::PRIMARY_RESOLVER_ID,
    )
}
