//! The Foxglove layout in `config/foxglove/motm.json` shows channels the logger writes: every
//! plotted path names a logged topic and a field of its JSON messages, and the image panel
//! shows the camera topic.

use motm_logger::json::ToJson;
use motm_logger::recorder::topics;
use motm_msgs::{self as msgs, Message, services};

#[test]
fn every_panel_of_the_layout_shows_a_logged_topic_and_field() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/foxglove/motm.json");
    let text = std::fs::read_to_string(&path).unwrap();
    let layout: serde_json::Value = serde_json::from_str(&text).unwrap();
    let panels = layout["configById"].as_object().unwrap();
    // The fields each plotted JSON topic has.
    let kinematics = [
        "ee_speed",
        "ee_velocity",
        "base_speed",
        "base_yaw_rate",
        "manipulability",
    ];
    let fields_of = |topic: &str| -> Vec<String> {
        let sample = match topic {
            t if t == format!("/{}", services::CONTROL_QP_STATUS) => {
                msgs::QpStatus::zeroed().to_json()
            }
            t if t == format!("/{}", services::BASE_VELOCITY_COMMAND) => {
                msgs::BaseVelocityCommand::zeroed().to_json()
            }
            t if t == topics::KINEMATICS => return kinematics.map(String::from).to_vec(),
            other => panic!("{other} is not a plotted topic of the logger"),
        };
        sample.as_object().unwrap().keys().cloned().collect()
    };
    let mut plots = 0;
    for (id, panel) in panels {
        if id.starts_with("Plot!") {
            for path in panel["paths"].as_array().unwrap() {
                let value = path["value"].as_str().unwrap();
                let (topic, field) = value.rsplit_once('.').unwrap();
                assert!(fields_of(topic).iter().any(|f| f == field), "{value}");
                plots += 1;
            }
        }
        if id.starts_with("Image!") {
            assert_eq!(panel["imageMode"]["imageTopic"], topics::CAMERA_IMAGE);
        }
    }
    assert!(plots >= 3);
    assert!(panels.keys().any(|id| id.starts_with("3D!")));
    assert!(panels.keys().any(|id| id.starts_with("Image!")));
}
