//! Removal of resources left by dead processes, and a check for leftovers.

use std::path::{Path, PathBuf};

use iceoryx2::node::{NodeCleanupFailure, NodeView};
use iceoryx2::prelude::*;

use crate::{BusError, IpcConfig};

/// Outcome of a dead-node cleanup.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CleanupReport {
    /// Dead nodes whose resources were removed.
    pub cleaned: u64,
    /// Dead nodes whose resources could not be removed (e.g. another process is on it).
    pub failed: u64,
}

/// Removes the iceoryx2 resources of every dead node (a process that died without cleaning
/// up) under `ipc`, without needing a node of one's own. A supervisor calls this after
/// `waitpid` reaped a dead child and before restarting it: a zombie still holds its node's
/// liveness lock, so reap first.
pub fn cleanup_dead_nodes(ipc: &IpcConfig) -> Result<CleanupReport, BusError> {
    let mut report = CleanupReport::default();
    for_each_node(ipc, |state| {
        if let NodeState::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(()) | Err(NodeCleanupFailure::ResourcesAlreadyCleanedUp) => report.cleaned += 1,
                Err(_) => report.failed += 1,
            }
        }
    })?;
    Ok(report)
}

/// Calls `each` with the state of every node under `ipc`.
fn for_each_node(
    ipc: &IpcConfig,
    mut each: impl FnMut(NodeState<ipc::Service>),
) -> Result<(), BusError> {
    let config = ipc.iceoryx2()?;
    Node::<ipc::Service>::list(&config, |state| {
        each(state);
        CallbackProgression::Continue
    })
    .map_err(|e| BusError::Node {
        process: "(cleanup)".to_owned(),
        detail: format!("cannot list nodes: {e:?}"),
    })
}

/// The live nodes under `ipc`, each as `name (pid N)`: a prefix with any is still in use (an
/// attached tool such as iceoryx2's `iox2 service hz` is one).
pub fn live_nodes(ipc: &IpcConfig) -> Result<Vec<String>, BusError> {
    let mut live = Vec::new();
    for_each_node(ipc, |state| {
        if let NodeState::Alive(view) = state {
            let name = view
                .details()
                .as_ref()
                .map_or_else(|| "(unnamed)".to_owned(), |d| d.name().to_string());
            match view.id().pid::<ipc::Service>() {
                Ok(pid) => live.push(format!("{name} (pid {})", pid.value())),
                Err(_) => live.push(name),
            }
        }
    })?;
    Ok(live)
}

/// Every file whose name starts with `prefix` in `/dev/shm` and (recursively) in iceoryx2's
/// runtime folder: what a set of processes with that prefix left behind. Empty after a clean
/// shutdown.
pub fn shared_memory_entries(ipc: &IpcConfig) -> Result<Vec<PathBuf>, BusError> {
    let config = ipc.iceoryx2()?;
    let root = PathBuf::from(config.global.root_path().to_string());
    let mut found = Vec::new();
    for dir in [Path::new("/dev/shm"), root.as_path()] {
        collect_prefixed(dir, &ipc.prefix, &mut found);
    }
    found.sort();
    Ok(found)
}

/// Appends the files under `dir` whose names start with `prefix`.
fn collect_prefixed(dir: &Path, prefix: &str, found: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if entry.file_name().to_string_lossy().starts_with(prefix) {
            found.push(path.clone());
        }
        if entry.file_type().is_ok_and(|t| t.is_dir()) {
            collect_prefixed(&path, prefix, found);
        }
    }
}

/// Removes the one resource iceoryx2 keeps after every process of a prefix has left: its
/// persistent node-counter segment (`<prefix>…node.<version>.global_mgmt` in `/dev/shm`).
/// A supervisor or test calls this at the very end of a run that used its own prefix, so
/// that the run leaves nothing behind. Returns whether a segment was removed.
///
/// # Safety
///
/// No process may be using the prefix of `ipc` any more (every node dropped or its process
/// reaped): a process still attached would have shared memory removed under it.
pub unsafe fn remove_domain(ipc: &IpcConfig) -> Result<bool, BusError> {
    let config = ipc.iceoryx2()?;
    // SAFETY: the caller guarantees that no process uses this prefix.
    unsafe { iceoryx2::testing::remove_global_mgmt_segment::<ipc::Service>(&config) }.map_err(|e| {
        BusError::Node {
            process: "(cleanup)".to_owned(),
            detail: format!("cannot remove the node-counter segment: {e:?}"),
        }
    })
}
