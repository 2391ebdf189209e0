//! What a bridge forwards and how it reaches its peers: a TOML file (`motm-zenoh --config
//! FILE`) or the topics of tasks run on another host, derived from the graph
//! ([`BridgeConfig::for_remote_tasks`]).

use std::path::Path;

use motm_msgs::services;
use serde::Deserialize;

pub use motm_graph::{REMOTE_BRIDGE, STACK_BRIDGE};

/// One bridge's settings.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BridgeConfig {
    /// Process name: the bridge's iceoryx2 node and heartbeat (`motm/v1/heartbeat/<name>`).
    pub name: String,
    /// Services read from the local iceoryx2 stack and put on zenoh.
    #[serde(default)]
    pub export: Vec<String>,
    /// Services received from zenoh and published on the local iceoryx2 stack.
    #[serde(default)]
    pub import: Vec<String>,
    /// zenoh endpoints this peer listens on, e.g. `tcp/0.0.0.0:7447`.
    #[serde(default)]
    pub listen: Vec<String>,
    /// zenoh endpoints of the peers to connect to, e.g. `tcp/gpu-box:7447`.
    #[serde(default)]
    pub connect: Vec<String>,
    /// A key-expression prefix in front of every service name (`robot1` gives
    /// `robot1/motm/v1/...`), so that several robots can share one zenoh network; empty: none.
    #[serde(default)]
    pub namespace: String,
    /// zenoh multicast scouting (peer discovery on the LAN); off by default, the peers are the
    /// `connect` endpoints.
    #[serde(default)]
    pub multicast_scouting: bool,
}

/// Which end of a remote-task bridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Side {
    /// The host of the stack (the drivers and the control loop).
    Stack,
    /// The host that runs the remote tasks.
    Remote,
}

impl BridgeConfig {
    /// Reads and checks a bridge config file; errors name the file and the key.
    pub fn from_file(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
        let config: Self = toml::from_str(&text).map_err(|e| {
            format!(
                "{}: {}",
                path.display(),
                e.to_string().lines().collect::<Vec<_>>().join(" ")
            )
        })?;
        config
            .validate()
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(config)
    }

    /// The bridge of one side when `tasks` (names of the graph's processes) run on the remote
    /// host: the stack exports every topic the tasks read that no remote task publishes, and
    /// imports what they publish and their heartbeats (and the remote bridge's), so that the
    /// supervisor, the watchdog, `motm run` and the logger see them as local processes; the
    /// remote side does the opposite. Errors name the unknown task.
    pub fn for_remote_tasks(tasks: &[String], side: Side) -> Result<Self, String> {
        let mut specs = Vec::new();
        for name in tasks {
            let spec = motm_graph::task(name)
                .filter(|t| t.is_process())
                .ok_or_else(|| {
                    format!(
                        "--remote-task {name}: not a process of the graph (processes: {})",
                        motm_graph::processes()
                            .map(|t| t.name)
                            .collect::<Vec<_>>()
                            .join(", ")
                    )
                })?;
            specs.push(spec);
        }
        let mut upstream: Vec<String> = Vec::new();
        let mut downstream: Vec<String> = Vec::new();
        for spec in &specs {
            for input in spec.inputs {
                let remote = specs.iter().any(|s| s.writes(input.name));
                if !remote && !upstream.iter().any(|t| t == input.name) {
                    upstream.push(input.name.to_owned());
                }
            }
            for output in spec.outputs {
                if !downstream.iter().any(|t| t == output.name) {
                    downstream.push(output.name.to_owned());
                }
            }
            downstream.push(services::heartbeat(spec.name));
        }
        downstream.push(services::heartbeat(REMOTE_BRIDGE));
        let (name, export, import) = match side {
            Side::Stack => (STACK_BRIDGE, upstream, downstream),
            Side::Remote => (REMOTE_BRIDGE, downstream, upstream),
        };
        let config = Self {
            name: name.to_owned(),
            export,
            import,
            listen: Vec::new(),
            connect: Vec::new(),
            namespace: String::new(),
            multicast_scouting: false,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks names and topics: a topic must have a known payload type and cross in one
    /// direction only (both ways, its samples would come back forever).
    pub fn validate(&self) -> Result<(), String> {
        if self.name.is_empty()
            || !self
                .name
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-')
        {
            return Err(format!(
                "name: '{}' must be a-z, 0-9 and '-' (it names the bridge's heartbeat)",
                self.name
            ));
        }
        for (key, topics) in [("export", &self.export), ("import", &self.import)] {
            for (i, topic) in topics.iter().enumerate() {
                if crate::lanes::kind_of(topic).is_none() {
                    return Err(format!(
                        "{key}[{i}]: '{topic}' is not a topic of the graph or a heartbeat \
                         (motm/v1/heartbeat/<process>)"
                    ));
                }
                if topics[..i].contains(topic) {
                    return Err(format!("{key}[{i}]: '{topic}' is listed twice"));
                }
            }
        }
        if let Some(topic) = self.export.iter().find(|t| self.import.contains(t)) {
            return Err(format!(
                "import: '{topic}' is also exported: a topic crosses one way only"
            ));
        }
        if let Some(topic) = self.import.iter().find(|t| {
            t.starts_with(services::HEARTBEAT_PREFIX) && **t == services::heartbeat(&self.name)
        }) {
            return Err(format!("import: '{topic}' is the bridge's own heartbeat"));
        }
        for (key, endpoints) in [("listen", &self.listen), ("connect", &self.connect)] {
            for (i, endpoint) in endpoints.iter().enumerate() {
                if !endpoint.starts_with("tcp/") {
                    return Err(format!(
                        "{key}[{i}]: '{endpoint}': only tcp/HOST:PORT endpoints are built in"
                    ));
                }
            }
        }
        Ok(())
    }

    /// The zenoh key expression of `service`.
    pub fn key_of(&self, service: &str) -> String {
        if self.namespace.is_empty() {
            service.to_owned()
        } else {
            format!("{}/{service}", self.namespace.trim_end_matches('/'))
        }
    }

    /// The zenoh session config: a peer on the `listen` and `connect` endpoints, with
    /// multicast scouting off unless asked for.
    pub fn zenoh_config(&self) -> Result<zenoh::Config, String> {
        let mut config = zenoh::Config::default();
        let json = |list: &[String]| serde_json::to_string(list).expect("strings serialise");
        let settings = [
            ("mode", "\"peer\"".to_owned()),
            ("listen/endpoints", json(&self.listen)),
            ("connect/endpoints", json(&self.connect)),
            (
                "scouting/multicast/enabled",
                self.multicast_scouting.to_string(),
            ),
        ];
        for (key, value) in settings {
            config
                .insert_json5(key, &value)
                .map_err(|e| format!("zenoh config {key} = {value}: {e}"))?;
        }
        Ok(config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::topics as t;

    #[test]
    fn remote_perception_crosses_its_inputs_one_way_and_its_target_and_heartbeats_back() {
        let tasks = vec!["perception".to_owned()];
        let stack = BridgeConfig::for_remote_tasks(&tasks, Side::Stack).unwrap();
        let remote = BridgeConfig::for_remote_tasks(&tasks, Side::Remote).unwrap();
        for input in motm_graph::PERCEPTION.inputs {
            assert!(
                stack.export.iter().any(|s| s == input.name),
                "{}",
                input.name
            );
        }
        assert_eq!(stack.export.len(), motm_graph::PERCEPTION.inputs.len());
        assert!(
            stack
                .import
                .contains(&t::PERCEPTION_TARGET.name().to_owned())
        );
        assert!(stack.import.contains(&services::heartbeat("perception")));
        assert!(stack.import.contains(&services::heartbeat(REMOTE_BRIDGE)));
        assert_eq!(stack.export, remote.import);
        assert_eq!(stack.import, remote.export);
        assert_eq!(stack.name, STACK_BRIDGE);
        assert_eq!(remote.name, REMOTE_BRIDGE);
    }

    #[test]
    fn two_remote_tasks_exchange_their_own_topics_on_the_remote_host() {
        let tasks = vec!["perception".to_owned(), "base-planner".to_owned()];
        let stack = BridgeConfig::for_remote_tasks(&tasks, Side::Stack).unwrap();
        // The planner reads perception's target on the remote host itself.
        assert!(
            !stack
                .export
                .contains(&t::PERCEPTION_TARGET.name().to_owned())
        );
        assert!(
            stack
                .import
                .contains(&t::PERCEPTION_TARGET.name().to_owned())
        );
        assert!(stack.import.contains(&t::BASE_PLAN.name().to_owned()));
    }

    #[test]
    fn bad_configs_name_the_key() {
        let err = BridgeConfig::for_remote_tasks(&["nosuch".to_owned()], Side::Stack).unwrap_err();
        assert!(err.contains("--remote-task nosuch"), "{err}");
        let base = BridgeConfig::for_remote_tasks(&["perception".to_owned()], Side::Stack).unwrap();
        let mut both = base.clone();
        both.import.push(both.export[0].clone());
        assert!(both.validate().unwrap_err().contains("also exported"));
        let mut unknown = base.clone();
        unknown.export.push("motm/v1/no/such".into());
        let err = unknown.validate().unwrap_err();
        assert!(
            err.starts_with(&format!("export[{}]", base.export.len())),
            "{err}"
        );
        let mut udp = base;
        udp.listen.push("udp/127.0.0.1:7447".into());
        assert!(udp.validate().unwrap_err().starts_with("listen[0]"));
    }

    #[test]
    fn a_config_file_with_an_unknown_key_names_the_file_and_key() {
        let dir = std::env::temp_dir().join(format!("motm-zenoh-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("bridge.toml");
        std::fs::write(&file, "name = \"b\"\nexprot = []\n").unwrap();
        let err = BridgeConfig::from_file(&file).unwrap_err();
        assert!(
            err.contains("bridge.toml") && err.contains("exprot"),
            "{err}"
        );
        std::fs::write(
            &file,
            "name = \"b\"\nimport = [\"motm/v1/perception/target\"]\nconnect = [\"tcp/127.0.0.1:7447\"]\n",
        )
        .unwrap();
        let config = BridgeConfig::from_file(&file).unwrap();
        assert_eq!(config.key_of("motm/v1/a"), "motm/v1/a");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
