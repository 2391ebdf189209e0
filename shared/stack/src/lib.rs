//! The stack configuration: the processes of one robot's stack, their rates and arguments,
//! the restart policy and the watchdog settings (`config/frankie.toml`, `config/fetch.toml`,
//! `config/husky_ur5.toml`). Not to be confused with the robot model in `config/robots/`.
//!
//! The processes named are the graph's ([`motm_graph::processes`]), every one of them and in its
//! order (upstream first); whether one is on the control path comes from the graph too.
//!
//! Process arguments are templates: `{config_dir}`, `{scenario}`, `{base_speed}`, `{robot}`, `{seed}`,
//! `{rate}` (the process's own rate), `{control_rate}`, `{stack}` (this file),
//! `{controllers}` (the controllers file, `controllers`) and `{calibration}` (the camera
//! calibration file perception uses) are replaced when the process is launched.

use std::path::{Path, PathBuf};

use motm_core::ModelError;
use motm_core::hot_swap::HotSwapConfig;
use motm_core::restart_policy::RestartPolicy;
use motm_core::watchdog::WatchdogConfig;
use motm_msgs::{MAX_SUPERVISED_PROCESSES, PROCESS_NAME_BYTES};
use serde::Deserialize;

/// The placeholders an argument template may use.
pub const PLACEHOLDERS: [&str; 10] = [
    "config_dir",
    "scenario",
    "base_speed",
    "robot",
    "seed",
    "rate",
    "control_rate",
    "stack",
    "controllers",
    "calibration",
];

/// One process of the stack.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessConfig {
    /// Process name = binary name = heartbeat name (e.g. `qp-resolver`).
    pub name: String,
    /// Cargo package that builds the binary (default `motm-<name>`).
    #[serde(default)]
    pub package: Option<String>,
    /// The process's own cycle rate, Hz; absent means the stack's control rate.
    #[serde(default)]
    pub rate_hz: Option<f64>,
    /// Argument templates (see the module documentation for the placeholders).
    #[serde(default)]
    pub args: Vec<String>,
}

impl ProcessConfig {
    /// The Cargo package of the binary.
    pub fn package(&self) -> String {
        self.package
            .clone()
            .unwrap_or_else(|| format!("motm-{}", self.name))
    }

    /// Whether the process is on the control path (its row of [`motm_graph::GRAPH`]): the
    /// watchdog safe-stops when its heartbeat goes stale or it reports deadline misses.
    pub fn control_path(&self) -> bool {
        motm_graph::task(&self.name).is_some_and(|t| t.control_path)
    }
}

/// A robot's stack: processes, rates, restart policy and watchdog settings.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StackConfig {
    /// Robot model name (`<config_dir>/robots/<robot>.toml`).
    pub robot: String,
    /// Scenario run when none is given (a name in `<config_dir>/scenarios/` or a path).
    pub scenario: String,
    /// Control rate, Hz (reacher, final phase, QP resolver, supervisor's mission task).
    #[serde(default = "default_control_rate")]
    pub control_rate_hz: f64,
    /// Default random seed.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Controller gains file (`OnTheMoveConfig`), relative to the config folder: the
    /// supervisor's mission and every control service (`{controllers}`) use it.
    #[serde(default = "default_controllers")]
    pub controllers: PathBuf,
    /// The palm camera's calibration file, relative to the config folder (default
    /// `cameras/palm.toml`): what perception (`{calibration}`) turns pixels into rays with on
    /// the robot. A stack with the simulated world hands perception the simulated camera's
    /// own calibration instead (see the supervisor's setup).
    #[serde(default = "default_calibration")]
    pub calibration: PathBuf,
    /// Longest wait for the processes to exit after SIGTERM before SIGKILL, ms.
    #[serde(default = "default_shutdown_grace")]
    pub shutdown_grace_ms: f64,
    /// Restart backoff.
    #[serde(default)]
    pub restart: RestartPolicy,
    /// Watchdog settings.
    #[serde(default)]
    pub watchdog: WatchdogConfig,
    /// Hot-swap timeouts and gap measurement (`[hot_swap]`).
    #[serde(default)]
    pub hot_swap: HotSwapConfig,
    /// The processes, in start order (stopped in reverse order).
    #[serde(rename = "process")]
    pub processes: Vec<ProcessConfig>,
    /// The stack that `motm run --hardware fake` runs in place of this one: the same robot
    /// with fake robots that speak the real protocols on loopback and drivers on their real
    /// backends (a name in the config folder, or a path).
    #[serde(default)]
    pub fake_hardware: Option<String>,
    /// A test stack: some of the graph's processes (still in its order) or stand-ins outside
    /// it (a heartbeat probe), instead of every process of the graph.
    #[serde(default)]
    pub partial: bool,
    /// The file this was read from.
    #[serde(skip)]
    pub path: PathBuf,
}

fn default_control_rate() -> f64 {
    200.0
}

fn default_seed() -> u64 {
    1
}

fn default_controllers() -> PathBuf {
    PathBuf::from(motm_core::on_the_move::CONTROLLERS_FILE)
}

fn default_calibration() -> PathBuf {
    PathBuf::from(motm_core::camera::CALIBRATION_FILE)
}

fn default_shutdown_grace() -> f64 {
    3000.0
}

/// Values substituted into argument templates at launch.
#[derive(Debug, Clone, PartialEq)]
pub struct LaunchContext {
    /// Config folder.
    pub config_dir: PathBuf,
    /// Scenario file.
    pub scenario: PathBuf,
    /// Base speed v_F, m/s (the scenario's, or an override).
    pub base_speed: f64,
    /// Random seed.
    pub seed: u64,
    /// Control rate, Hz (overrides the stack's `control_rate_hz`).
    pub control_rate_hz: f64,
    /// The controllers file ([`StackConfig::controllers_file`]).
    pub controllers: PathBuf,
    /// The camera calibration file perception reads.
    pub calibration: PathBuf,
}

impl StackConfig {
    /// Reads and checks a stack file; errors name the file and the key.
    pub fn from_file(path: &Path) -> Result<Self, ModelError> {
        let mut config: StackConfig = ModelError::parse_toml(path)?;
        config.path = path.to_path_buf();
        config.validate()?;
        Ok(config)
    }

    /// The stack file of `name`: `name` itself when it is an existing file or reads as a
    /// path (it ends in `.toml` or holds a `/`), else `<config_dir>/<name>.toml`.
    pub fn resolve(config_dir: &Path, name: &str) -> PathBuf {
        let direct = PathBuf::from(name);
        if direct.is_file() || name.ends_with(".toml") || name.contains('/') {
            direct
        } else {
            config_dir.join(format!("{name}.toml"))
        }
    }

    /// Checks names, rates, templates and the nested settings.
    pub fn validate(&self) -> Result<(), ModelError> {
        let invalid = |key: String, message: String| ModelError::invalid(&self.path, key, message);
        positive(&self.path, "control_rate_hz", self.control_rate_hz)?;
        positive(&self.path, "shutdown_grace_ms", self.shutdown_grace_ms)?;
        self.restart
            .validate()
            .map_err(|(key, message)| invalid(format!("restart.{key}"), message))?;
        self.watchdog
            .validate()
            .map_err(|(key, message)| invalid(format!("watchdog.{key}"), message))?;
        self.hot_swap
            .validate()
            .map_err(|(key, message)| invalid(format!("hot_swap.{key}"), message))?;
        if self.processes.is_empty() || self.processes.len() > MAX_SUPERVISED_PROCESSES {
            return Err(invalid(
                "process".into(),
                format!(
                    "needs 1 to {MAX_SUPERVISED_PROCESSES} processes, got {}",
                    self.processes.len()
                ),
            ));
        }
        for (i, process) in self.processes.iter().enumerate() {
            let key = |field: &str| format!("process[{i}].{field}");
            if !valid_process_name(&process.name) {
                return Err(invalid(
                    key("name"),
                    format!(
                        "'{}' must be 1 to {PROCESS_NAME_BYTES} characters of a-z, 0-9 and '-'",
                        process.name
                    ),
                ));
            }
            if process.name == "supervisor" {
                return Err(invalid(
                    key("name"),
                    "the supervisor is not one of its own processes".into(),
                ));
            }
            if self.processes[..i].iter().any(|p| p.name == process.name) {
                return Err(invalid(
                    key("name"),
                    format!("'{}' is listed twice", process.name),
                ));
            }
            if let Some(rate) = process.rate_hz {
                positive(&self.path, &key("rate_hz"), rate)?;
            }
            for (j, arg) in process.args.iter().enumerate() {
                check_template(arg)
                    .map_err(|message| invalid(format!("{}[{j}]", key("args")), message))?;
            }
        }
        self.check_graph()
    }

    /// Checks that the processes are the graph's, in its order, with stand-ins before their
    /// drivers: an unknown or missing one is an error naming the file and the process (a [`Self::partial`] stack may leave
    /// processes out and add stand-ins).
    fn check_graph(&self) -> Result<(), ModelError> {
        let graph: Vec<&str> = motm_graph::processes().map(|t| t.name).collect();
        let position = |name: &str| graph.iter().position(|g| *g == name);
        let mut last: Option<(usize, &str)> = None;
        for (i, process) in self.processes.iter().enumerate() {
            let key = format!("process[{i}].name");
            if let Some(stand_in) = motm_graph::stand_in(&process.name) {
                if !self.processes[i + 1..]
                    .iter()
                    .any(|p| p.name == stand_in.serves)
                {
                    return Err(ModelError::invalid(
                        &self.path,
                        key,
                        format!(
                            "'{}' stands in for the hardware of '{}', which must come after it",
                            process.name, stand_in.serves
                        ),
                    ));
                }
                continue;
            }
            let Some(at) = position(&process.name) else {
                if self.partial {
                    continue;
                }
                return Err(ModelError::invalid(
                    &self.path,
                    key,
                    format!(
                        "'{}' is not a process of the graph (processes: {})",
                        process.name,
                        graph.join(", ")
                    ),
                ));
            };
            if let Some((before, name)) = last
                && before > at
            {
                return Err(ModelError::invalid(
                    &self.path,
                    key,
                    format!(
                        "'{}' must come before '{name}' (the graph's order, upstream first: {})",
                        process.name,
                        graph.join(", ")
                    ),
                ));
            }
            last = Some((at, process.name.as_str()));
        }
        if !self.partial
            && let Some(missing) = graph.iter().find(|g| {
                // A hot standby is optional: a stack without it runs the primary alone.
                self.process(g).is_none()
                    && motm_graph::task(g).is_none_or(|t| t.standby_of.is_none())
            })
        {
            return Err(ModelError::invalid(
                &self.path,
                "process",
                format!("the graph's process '{missing}' is missing"),
            ));
        }
        Ok(())
    }

    /// The `--backend` each driver of the stack is started with (`sim` when its arguments
    /// name none), in stack order.
    pub fn driver_backends(&self) -> Vec<(String, String)> {
        self.processes
            .iter()
            .filter(|p| motm_graph::STAND_INS.iter().any(|s| s.serves == p.name))
            .map(|p| {
                let flag = p.args.iter().position(|a| a == "--backend");
                let inline = p.args.iter().find_map(|a| a.strip_prefix("--backend="));
                let backend = flag
                    .and_then(|i| p.args.get(i + 1))
                    .map(String::as_str)
                    .or(inline)
                    .unwrap_or("sim");
                (p.name.clone(), backend.to_owned())
            })
            .collect()
    }

    /// The processes that stand in for a robot's hardware (fake robots).
    pub fn stand_ins(&self) -> impl Iterator<Item = &ProcessConfig> {
        self.processes
            .iter()
            .filter(|p| motm_graph::stand_in(&p.name).is_some())
    }

    /// The controllers file, in `config_dir` unless `controllers` is absolute.
    pub fn controllers_file(&self, config_dir: &Path) -> PathBuf {
        config_dir.join(&self.controllers)
    }

    /// The camera calibration file, in `config_dir` unless `calibration` is absolute.
    pub fn calibration_file(&self, config_dir: &Path) -> PathBuf {
        config_dir.join(&self.calibration)
    }

    /// The named process, if listed.
    pub fn process(&self, name: &str) -> Option<&ProcessConfig> {
        self.processes.iter().find(|p| p.name == name)
    }

    /// The rate of `process` under control rate `control_rate_hz`, Hz.
    pub fn rate_of(&self, process: &ProcessConfig, control_rate_hz: f64) -> f64 {
        process.rate_hz.unwrap_or(control_rate_hz)
    }

    /// The arguments of `process` with every placeholder replaced.
    pub fn expand_args(&self, process: &ProcessConfig, context: &LaunchContext) -> Vec<String> {
        let rate = self.rate_of(process, context.control_rate_hz);
        let values = [
            ("config_dir", context.config_dir.display().to_string()),
            ("scenario", context.scenario.display().to_string()),
            ("base_speed", context.base_speed.to_string()),
            ("robot", self.robot.clone()),
            ("seed", context.seed.to_string()),
            ("rate", rate.to_string()),
            ("control_rate", context.control_rate_hz.to_string()),
            ("stack", self.path.display().to_string()),
            ("controllers", context.controllers.display().to_string()),
            ("calibration", context.calibration.display().to_string()),
        ];
        process
            .args
            .iter()
            .map(|arg| {
                values.iter().fold(arg.clone(), |text, (name, value)| {
                    text.replace(&format!("{{{name}}}"), value)
                })
            })
            .collect()
    }
}

/// Process names: what iceoryx2 node names and heartbeat names allow here.
fn valid_process_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= PROCESS_NAME_BYTES
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-')
}

/// A finite value > 0, or an error naming `key`.
fn positive(path: &Path, key: &str, value: f64) -> Result<(), ModelError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(ModelError::invalid(
            path,
            key,
            format!("must be a finite number > 0, got {value}"),
        ))
    }
}

/// Checks that every `{...}` in `arg` is a known placeholder.
fn check_template(arg: &str) -> Result<(), String> {
    let mut rest = arg;
    while let Some(open) = rest.find('{') {
        let after = &rest[open + 1..];
        let Some(close) = after.find('}') else {
            return Err(format!("'{arg}': unclosed '{{'"));
        };
        let name = &after[..close];
        if !PLACEHOLDERS.contains(&name) {
            return Err(format!(
                "'{arg}': unknown placeholder {{{name}}}; expected one of {}",
                PLACEHOLDERS.map(|p| format!("{{{p}}}")).join(", ")
            ));
        }
        rest = &after[close + 1..];
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
    }

    fn parse(text: &str) -> Result<StackConfig, ModelError> {
        let path = Path::new("stack.toml");
        let mut config: StackConfig = ModelError::parse_toml_str(path, text)?;
        config.path = path.to_path_buf();
        config.validate()?;
        Ok(config)
    }

    /// The stack files of the config folder: its `*.toml` with a `[[process]]` table.
    fn shipped_stacks() -> Vec<PathBuf> {
        let mut stacks: Vec<PathBuf> = std::fs::read_dir(config_dir())
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .filter(|p| {
                let text = std::fs::read_to_string(p).unwrap();
                toml::from_str::<toml::Table>(&text)
                    .unwrap()
                    .contains_key("process")
            })
            .collect();
        stacks.sort();
        stacks
    }

    #[test]
    fn the_fake_hardware_stack_has_fake_robots_and_real_backends() {
        let frankie = StackConfig::from_file(&config_dir().join("frankie.toml")).unwrap();
        assert_eq!(
            frankie.driver_backends(),
            [
                ("panda-driver".to_string(), "sim".to_string()),
                ("ld60-driver".to_string(), "sim".to_string())
            ]
        );
        assert_eq!(frankie.stand_ins().count(), 0);
        let fake_name = frankie.fake_hardware.as_deref().expect("frankie names one");
        let fake = StackConfig::from_file(&StackConfig::resolve(&config_dir(), fake_name)).unwrap();
        assert_eq!(fake.robot, frankie.robot);
        assert!(fake.fake_hardware.is_none());
        let stand_ins: Vec<&str> = fake.stand_ins().map(|p| p.name.as_str()).collect();
        assert_eq!(stand_ins, ["fake-panda", "fake-ld60"]);
        assert_eq!(
            fake.driver_backends(),
            [
                ("panda-driver".to_string(), "fci".to_string()),
                ("ld60-driver".to_string(), "arnl".to_string())
            ]
        );
        // The other processes run as in the sim stack.
        for p in &frankie.processes {
            if !p.name.ends_with("-driver") {
                assert_eq!(fake.process(&p.name), Some(p), "{}", p.name);
            }
        }
    }

    #[test]
    fn every_shipped_stack_loads_and_names_the_graphs_processes_in_order() {
        let stacks = shipped_stacks();
        let names: Vec<String> = stacks
            .iter()
            .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
            .collect();
        for robot in [
            "frankie",
            "fetch",
            "husky_ur5",
            "frankie_arnl",
            "frankie_fake",
        ] {
            assert!(names.iter().any(|n| n == robot), "{robot}: {names:?}");
        }
        let graph: Vec<&str> = motm_graph::processes().map(|t| t.name).collect();
        for path in &stacks {
            let stack = StackConfig::from_file(path).unwrap();
            assert!(!stack.partial, "{}", path.display());
            let listed: Vec<&str> = stack
                .processes
                .iter()
                .map(|p| p.name.as_str())
                .filter(|n| motm_graph::stand_in(n).is_none())
                .collect();
            assert_eq!(listed, graph, "{}", path.display());
            for process in &stack.processes {
                assert_eq!(
                    process.control_path(),
                    motm_graph::task(&process.name).is_some_and(|t| t.control_path),
                    "{}: {}",
                    path.display(),
                    process.name
                );
            }
            assert!(stack.process("qp-resolver").unwrap().control_path());
            assert!(!stack.process("sim-world").unwrap().control_path());
            // Every control service and the mission take their gains from the one file.
            let controllers = stack.controllers_file(&config_dir());
            motm_core::on_the_move::OnTheMoveConfig::load(&controllers).unwrap();
            for name in [
                "perception",
                "base-planner",
                "reacher",
                "final-phase",
                "qp-resolver",
            ] {
                let args = &stack.process(name).unwrap().args;
                assert!(
                    args.windows(2)
                        .any(|w| w[0] == "--controllers" && w[1] == "{controllers}"),
                    "{}: {name} {args:?}",
                    path.display()
                );
            }
        }
    }

    #[test]
    fn a_stack_off_the_graph_is_an_error_naming_the_file_and_the_process() {
        let graph: Vec<&str> = motm_graph::processes().map(|t| t.name).collect();
        let stack = |names: &[&str], partial: bool| {
            let mut text = format!("robot = \"frankie\"\nscenario = \"x\"\npartial = {partial}\n");
            for name in names {
                text.push_str(&format!("[[process]]\nname = \"{name}\"\n"));
            }
            parse(&text)
        };
        stack(&graph, false).unwrap();
        let error = |names: &[&str]| stack(names, false).unwrap_err().to_string();

        let mut unknown = graph.clone();
        unknown.insert(2, "no-such-process");
        let err = error(&unknown);
        assert!(
            err.contains("stack.toml")
                && err.contains("process[2].name")
                && err.contains("'no-such-process' is not a process of the graph"),
            "{err}"
        );

        let missing: Vec<&str> = graph.iter().copied().filter(|n| *n != "reacher").collect();
        let err = error(&missing);
        assert!(
            err.contains("stack.toml") && err.contains("'reacher' is missing"),
            "{err}"
        );

        let mut swapped = graph.clone();
        swapped.swap(0, 1);
        let err = error(&swapped);
        assert!(
            err.contains("stack.toml")
                && err.contains("process[1].name")
                && err.contains(&format!("'{}' must come before '{}'", graph[0], graph[1])),
            "{err}"
        );

        // A stand-in comes before the driver it serves.
        let mut with_fake = graph.clone();
        let driver = with_fake.iter().position(|n| *n == "ld60-driver").unwrap();
        with_fake.insert(driver, "fake-ld60");
        stack(&with_fake, false).unwrap();
        with_fake.remove(driver);
        with_fake.insert(driver + 1, "fake-ld60");
        let err = error(&with_fake);
        assert!(
            err.contains(&format!("process[{}].name", driver + 1))
                && err.contains("'fake-ld60' stands in for the hardware of 'ld60-driver'"),
            "{err}"
        );

        // A partial (test) stack may leave processes out and add stand-ins, in graph order.
        let partial = stack(&["heartbeat-probe", "qp-resolver"], true).unwrap();
        assert!(partial.process("qp-resolver").unwrap().control_path());
        assert!(!partial.process("heartbeat-probe").unwrap().control_path());
        let err = stack(&["watchdog", "qp-resolver"], true)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("'qp-resolver' must come before 'watchdog'"),
            "{err}"
        );
    }

    #[test]
    fn templates_expand_with_the_process_rate() {
        let stack = parse(
            r#"
            robot = "frankie"
            scenario = "exp1-dynamic"
            partial = true
            [[process]]
            name = "sim-world"
            rate_hz = 1000.0
            args = ["--scenario", "{scenario}", "--rate", "{rate}", "--seed={seed}", "--base-speed", "{base_speed}"]
            [[process]]
            name = "reacher"
            args = ["--rate", "{rate}", "--robot", "{robot}", "--stack", "{stack}", "--controllers", "{controllers}"]
            "#,
        )
        .unwrap();
        let context = LaunchContext {
            config_dir: PathBuf::from("/c"),
            scenario: PathBuf::from("/c/s.toml"),
            base_speed: 0.5,
            seed: 7,
            control_rate_hz: 1000.0,
            controllers: PathBuf::from("/c/controllers.toml"),
            calibration: PathBuf::from("/c/cameras/palm.toml"),
        };
        assert_eq!(
            stack.expand_args(&stack.processes[0], &context),
            [
                "--scenario",
                "/c/s.toml",
                "--rate",
                "1000",
                "--seed=7",
                "--base-speed",
                "0.5"
            ]
        );
        assert_eq!(
            stack.expand_args(&stack.processes[1], &context),
            [
                "--rate",
                "1000",
                "--robot",
                "frankie",
                "--stack",
                "stack.toml",
                "--controllers",
                "/c/controllers.toml"
            ]
        );
        assert_eq!(stack.processes[1].package(), "motm-reacher");
    }

    #[test]
    fn bad_stacks_name_the_key() {
        let base = "robot = \"frankie\"\nscenario = \"x\"\n";
        let cases = [
            (
                "[[process]]\nname = \"a\"\nargs = [\"{nope}\"]\n",
                "process[0].args[0]",
            ),
            ("[[process]]\nname = \"A b\"\n", "process[0].name"),
            (
                "[[process]]\nname = \"a\"\n[[process]]\nname = \"a\"\n",
                "process[1].name",
            ),
            (
                "[[process]]\nname = \"a\"\nrate_hz = -1.0\n",
                "process[0].rate_hz",
            ),
            (
                "[restart]\nmultiplier = 0.1\n[[process]]\nname = \"a\"\n",
                "restart.multiplier",
            ),
            (
                "[watchdog]\nstale_cycles = 0\n[[process]]\nname = \"a\"\n",
                "watchdog.stale_cycles",
            ),
            (
                "control_rate_hz = 0.0\n[[process]]\nname = \"a\"\n",
                "control_rate_hz",
            ),
            (
                "[hot_swap]\ngap_window_periods = 0\n[[process]]\nname = \"a\"\n",
                "hot_swap.gap_window_periods",
            ),
        ];
        for (text, key) in cases {
            let err = parse(&format!("{base}{text}")).unwrap_err().to_string();
            assert!(
                err.contains("stack.toml") && err.contains(key),
                "{key}: {err}"
            );
        }
        // Unknown keys are errors too, located by line.
        let err = parse(&format!("{base}[[process]]\nname = \"a\"\nrte_hz = 1.0\n"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("rte_hz"), "{err}");
    }
}
