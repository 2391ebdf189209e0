use super::*;
use motm_core::mission::TaskKind;
use nalgebra::Vector3;

/// The project's `config/` folder.
fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config")
}

const VALID: &str = r#"
name = "test"
robot = "frankie"
start_pose = [0.0, 0.0, 0.0]
base_speed = 0.3

[[objects]]
position = [2.0, 0.0, 0.45]
motion = "random"
speed = 0.03
heading = 1.57
place = [4.0, 0.0, 0.35]
"#;

/// Parses `text` as if read from `bad.toml` and returns the error message.
fn error_of(text: &str) -> String {
    match Scenario::from_toml_str(Path::new("scenarios/bad.toml"), text) {
        Ok(s) => panic!("accepted a bad scenario: {s:?}"),
        Err(e) => e.to_string(),
    }
}

/// Asserts that the error names the file and the key.
fn assert_names(message: &str, key: &str) {
    assert!(
        message.starts_with("scenarios/bad.toml: "),
        "no file in: {message}"
    );
    assert!(message.contains(key), "no key `{key}` in: {message}");
}

#[test]
fn the_design_example_parses_with_default_noise() {
    let s = Scenario::from_toml_str(Path::new("example.toml"), VALID).unwrap();
    assert_eq!(s.objects.len(), 1);
    assert_eq!(s.objects[0].motion, Motion::Random);
    assert_eq!(s.objects[0].motion_speed(), 0.03);
    assert_eq!(s.noise, Noise::default());
    assert_eq!(s.path, Path::new("example.toml"));
    let tasks = s.mission_tasks();
    assert_eq!(tasks.len(), 2);
    assert_eq!(tasks[0].kind, TaskKind::Pick);
    assert_eq!(tasks[1].kind, TaskKind::Place);
    assert_eq!(tasks[1].position, Vector3::new(4.0, 0.0, 0.35));
}

#[test]
fn every_shipped_scenario_loads() {
    let dir = config_dir().join("scenarios");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .map(|p| {
            let s = Scenario::from_file(&p).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(
                Some(s.name.as_str()),
                p.file_stem().and_then(|n| n.to_str())
            );
            s.name
        })
        .collect();
    names.sort();
    let expected = [
        "button",
        "button-swap",
        "exp1-dynamic",
        "exp1-static",
        "exp2",
        "mission-alternating-sides",
        "mission-fetch-u-turn",
        "mission-husky-zigzag",
        "mission-place-behind",
        "mission-press-between",
        "mission-three-mixed",
        "mission-u-turn-place",
        "mission-zigzag",
        "platforms-fetch",
        "platforms-frankie",
        "platforms-husky_ur5",
        "two-in-a-row",
    ];
    assert_eq!(names, expected);
}

#[test]
fn shipped_layouts_follow_the_paper() {
    let load = |name: &str| {
        Scenario::from_file(&config_dir().join(format!("scenarios/{name}.toml"))).unwrap()
    };
    let dynamic = load("exp1-dynamic");
    assert_eq!(dynamic.objects[0].motion, Motion::Random);
    assert_eq!(dynamic.objects[0].motion_speed(), 0.03);
    let exp2 = load("exp2");
    assert_eq!(exp2.objects.len(), 10);
    for object in &exp2.objects {
        let distance = (Vector3::from(object.place) - Vector3::from(object.position))
            .xy()
            .norm();
        assert!((2.4..=3.6).contains(&distance), "placed {distance} m away");
    }
    let button = load("button");
    assert_eq!(button.buttons.len(), 1);
    assert_eq!(
        button.mission_tasks().last().unwrap().kind,
        TaskKind::PressButton
    );
    for robot in ROBOT_NAMES {
        assert_eq!(load(&format!("platforms-{robot}")).robot, robot);
    }
}

#[test]
fn unknown_keys_are_named() {
    assert_names(&error_of(&format!("colour = \"red\"\n{VALID}")), "colour");
    let in_object = VALID.replace("motion = \"random\"", "motion = \"random\"\nmass = 0.1");
    assert_names(&error_of(&in_object), "objects[0].mass");
    let in_noise = format!("{VALID}\n[noise]\nlatency = 0.02\njitter = 0.1\n");
    assert_names(&error_of(&in_noise), "noise.jitter");
}

#[test]
fn missing_required_keys_are_named() {
    assert_names(
        &error_of(&VALID.replace("base_speed = 0.3", "")),
        "base_speed",
    );
    assert_names(
        &error_of(&VALID.replace("place = [4.0, 0.0, 0.35]", "")),
        "objects[0].place",
    );
    assert_names(
        &error_of(&VALID.replace("speed = 0.03", "")),
        "objects[0].speed",
    );
    let line = VALID
        .replace("\"random\"", "\"line\"")
        .replace("heading = 1.57", "");
    assert_names(&error_of(&line), "objects[0].heading");
}

#[test]
fn bad_values_are_named() {
    let message = error_of(&VALID.replace("speed = 0.03", "speed = -0.03"));
    assert_names(&message, "objects[0].speed");
    assert!(message.contains("-0.03"), "{message}");
    assert_names(
        &error_of(&VALID.replace("speed = 0.03", "speed = nan")),
        "objects[0].speed",
    );
    assert_names(
        &error_of(&VALID.replace("base_speed = 0.3", "base_speed = inf")),
        "base_speed",
    );
    assert_names(
        &error_of(&VALID.replace("base_speed = 0.3", "base_speed = 0.0")),
        "base_speed",
    );
    assert_names(
        &error_of(&VALID.replace("\"frankie\"", "\"r2d2\"")),
        "robot",
    );
    assert_names(
        &error_of(&VALID.replace("\"random\"", "\"circle\"")),
        "objects[0].motion",
    );
    assert_names(
        &error_of(&VALID.replace("base_speed = 0.3", "base_speed = \"fast\"")),
        "base_speed",
    );
    assert_names(
        &error_of(&VALID.replace("start_pose = [0.0, 0.0, 0.0]", "start_pose = [0.0, 0.0]")),
        "start_pose",
    );
    assert_names(
        &error_of(&VALID.replace("position = [2.0, 0.0, 0.45]", "position = [2.0, 0.0, -0.1]")),
        "objects[0].position",
    );
    assert_names(
        &error_of(&format!("{VALID}\n[noise]\nlatency = -0.01\n")),
        "noise.latency",
    );
    assert_names(
        &error_of(&format!("{VALID}\n[noise]\nodometry_drift = nan\n")),
        "noise.odometry_drift",
    );
    let static_with_speed = VALID.replace("\"random\"", "\"static\"");
    assert_names(&error_of(&static_with_speed), "objects[0].speed");
    let object = &VALID[VALID.find("[[objects]]").unwrap()..];
    let most = format!("{VALID}{}", object.repeat(MAX_SIM_OBJECTS - 1));
    assert!(Scenario::from_toml_str(Path::new("most.toml"), &most).is_ok());
    let message = error_of(&format!("{most}{object}"));
    assert_names(&message, "objects");
    assert!(
        message.contains(&format!("got {}", MAX_SIM_OBJECTS + 1)),
        "{message}"
    );
}

#[test]
fn syntax_errors_name_the_line() {
    let message = error_of("name = \"x\nrobot = \"frankie\"\n");
    assert_names(&message, "line 1");
}

#[test]
fn a_missing_file_is_named() {
    let message = Scenario::from_file(Path::new("/nonexistent/scenario.toml"))
        .unwrap_err()
        .to_string();
    assert!(message.contains("/nonexistent/scenario.toml"), "{message}");
}

#[test]
fn base_speed_override_is_checked() {
    let mut s = Scenario::from_toml_str(Path::new("example.toml"), VALID).unwrap();
    s.set_base_speed(0.4).unwrap();
    assert_eq!(s.base_speed, 0.4);
    let message = s.set_base_speed(-1.0).unwrap_err();
    assert!(
        message.starts_with("--base-speed -1:")
            && message.contains("example.toml")
            && message.contains("base_speed"),
        "{message}"
    );
    assert_eq!(s.base_speed, 0.4);
}

#[test]
fn a_button_after_an_object_is_pressed_right_after_its_place() {
    let text = format!(
        "{VALID}\n[[objects]]\nposition = [6.0, 0.0, 0.45]\nmotion = \"static\"\nplace = [8.0, 0.0, 0.35]\n\n\
         [[buttons]]\nposition = [5.0, 0.0, 0.5]\nafter_object = 0\n"
    );
    let s = Scenario::from_toml_str(Path::new("scenarios/bad.toml"), &text).unwrap();
    let kinds: Vec<TaskKind> = s.mission_tasks().iter().map(|t| t.kind).collect();
    // The button names object 0: it is pressed between its place and the next pick.
    use TaskKind::{Pick, Place, PressButton};
    assert_eq!(kinds, [Pick, Place, PressButton, Pick, Place]);
    let bad = text.replace("after_object = 0", "after_object = 7");
    let message = Scenario::from_toml_str(Path::new("scenarios/bad.toml"), &bad)
        .unwrap_err()
        .to_string();
    assert_names(&message, "buttons[0].after_object");
}

#[test]
fn every_shipped_scenario_gives_the_control_processes_the_simulators_mission() {
    let dir = config_dir().join("scenarios");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let scenario = Scenario::from_file(&path).unwrap();
        let mission = motm_core::mission_file::MissionFile::from_file(&path).unwrap();
        assert_eq!(
            mission.tasks,
            scenario.mission_tasks(),
            "{}",
            path.display()
        );
        assert_eq!(
            (mission.robot.as_str(), mission.base_speed),
            (scenario.robot.as_str(), scenario.base_speed),
            "{}",
            path.display()
        );
        checked += 1;
    }
    assert!(checked >= 10, "{checked} scenarios");
}
