//! JSON views of the motm payloads (one JSON channel per iceoryx2 service, for plots and raw
//! inspection) and the jsonschema of a JSON channel, inferred from its first message (every
//! message of a channel has the same shape: the payloads are fixed-size).

use motm_msgs as msgs;
use serde_json::{Value, json};

/// A payload with a JSON view.
pub trait ToJson {
    /// The payload's fields as a JSON object (arrays cut to their used length, codes named).
    fn to_json(&self) -> Value;
}

/// The first `count` entries of `values` (at most all of them).
fn used(values: &[f64], count: u32) -> &[f64] {
    &values[..(count as usize).min(values.len())]
}

/// Name of an enumeration code, `"unknown"` when invalid.
fn code_name<T: TryFrom<u32> + std::fmt::Debug>(code: u32) -> String {
    T::try_from(code).map_or_else(|_| "unknown".into(), |v| format!("{v:?}"))
}

impl ToJson for msgs::JointState {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "position": used(&self.position, self.joint_count),
            "velocity": used(&self.velocity, self.joint_count),
        })
    }
}

impl ToJson for msgs::GripperState {
    fn to_json(&self) -> Value {
        json!({ "seq": self.header.seq, "width": self.width, "grasping": self.grasping })
    }
}

impl ToJson for msgs::BaseOdometry {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "x": self.x, "y": self.y, "yaw": self.yaw, "v": self.v, "omega": self.omega,
        })
    }
}

impl ToJson for msgs::BaseVelocityCommand {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq, "v": self.v, "omega": self.omega,
            "resolver_id": self.resolver_id,
        })
    }
}

impl ToJson for msgs::ArmVelocityCommand {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "velocity": used(&self.velocity, self.joint_count),
            "resolver_id": self.resolver_id,
        })
    }
}

impl ToJson for msgs::GripperCommand {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "controller_id": self.controller_id,
            "action": code_name::<msgs::GripperAction>(self.action),
        })
    }
}

impl ToJson for msgs::TwistCommand {
    fn to_json(&self) -> Value {
        let t = &self.twist;
        json!({
            "seq": self.header.seq,
            "controller_id": self.controller_id,
            "phase": code_name::<msgs::TaskPhase>(self.phase),
            "twist": t,
            "linear_speed": (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt(),
            "task_index": self.task_index,
            "progress": code_name::<msgs::TaskProgressCode>(self.progress),
        })
    }
}

impl ToJson for msgs::TargetEstimate {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "image_age_ms": self.header.stamp_ns.saturating_sub(self.image_stamp_ns) as f64 / 1e6,
            "position": self.position,
            "velocity": self.velocity,
            "visible": self.visible,
            "task_index": self.task_index,
        })
    }
}

impl ToJson for msgs::BasePlan {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "closest_approach": self.closest_approach,
            "time_to_range": self.time_to_range,
            "range_entry_pose": self.range_entry_pose,
            "task_index": self.task_index,
            "passed": self.passed,
            "missed_passes": self.missed_passes,
            "gave_up": self.gave_up,
        })
    }
}

impl ToJson for msgs::QpStatus {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "outcome": code_name::<msgs::QpOutcome>(self.outcome),
            "outcome_code": self.outcome,
            "iterations": self.iterations,
            "solve_time_us": self.solve_time_ns as f64 / 1e3,
            "objective": self.objective,
            "slack_norm": self.slack_norm,
        })
    }
}

impl ToJson for msgs::ActiveController {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "controller_id": self.controller_id,
            "variant": code_name::<msgs::ControllerVariant>(self.variant),
        })
    }
}

impl ToJson for msgs::MissionState {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "task_index": self.task_index,
            "task_count": self.task_count,
            "task_kind": code_name::<msgs::TaskKindCode>(self.task_kind),
            "phase": code_name::<msgs::TaskPhase>(self.phase),
            "phase_code": self.phase,
            "current_target": self.current_target,
        })
    }
}

impl ToJson for msgs::SafeStop {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "active": self.active,
            "reason": code_name::<msgs::SafeStopReason>(self.reason),
            "fault_raises": self.fault_raises,
        })
    }
}

impl ToJson for msgs::Heartbeat {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "process": self.process_name(),
            "pid": self.pid,
            "state": code_name::<msgs::ProcessState>(self.state),
            "cycles": self.cycles,
            "deadline_misses": self.deadline_misses,
            "rejected_messages": self.rejected_messages,
            "p99_cycle_us": self.p99_cycle_ns as f64 / 1e3,
            "max_cycle_us": self.max_cycle_ns as f64 / 1e3,
        })
    }
}

impl ToJson for msgs::SupervisorStatus {
    fn to_json(&self) -> Value {
        let processes: Vec<Value> = self
            .processes()
            .iter()
            .map(|p| {
                json!({
                    "name": p.name(),
                    "pid": p.pid,
                    "state": code_name::<msgs::SupervisedState>(p.state),
                    "restarts": p.restarts,
                    "last_exit": p.last_exit,
                })
            })
            .collect();
        json!({
            "seq": self.header.seq,
            "shutting_down": self.shutting_down == 1,
            "processes": processes,
        })
    }
}

impl ToJson for msgs::SwapRequest {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "request_id": self.request_id,
            "process": code_name::<msgs::SwappableProcess>(self.process),
            "variant": code_name::<msgs::ControllerVariant>(self.variant),
            "command_timeout_ms": self.command_timeout_ms,
        })
    }
}

impl ToJson for msgs::SwapStatus {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "request_id": self.request_id,
            "stage": code_name::<msgs::SwapStageCode>(self.stage),
            "failure": code_name::<msgs::SwapFailureCode>(self.failure),
            "variant": code_name::<msgs::ControllerVariant>(self.variant),
            "old_pid": self.old_pid,
            "new_pid": self.new_pid,
            "old_controller_id": self.old_controller_id,
            "new_controller_id": self.new_controller_id,
            "heartbeat_wait_ms": self.heartbeat_wait_ns as f64 / 1e6,
            "command_wait_ms": self.command_wait_ns as f64 / 1e6,
            "command_gap_ms": self.command_gap_ns as f64 / 1e6,
            "stamp_gap_ms": self.stamp_gap_ns as f64 / 1e6,
            "base_speed": self.base_speed,
        })
    }
}

impl ToJson for msgs::SimTruth {
    fn to_json(&self) -> Value {
        let count = (self.object_count as usize).min(msgs::MAX_SIM_OBJECTS);
        json!({
            "seq": self.header.seq,
            "sim_time": self.sim_time,
            "outcome": code_name::<msgs::SimOutcome>(self.outcome),
            "tool_position": self.tool_position,
            "base_pose": self.base_pose,
            "held_object": self.held_object,
            "buttons_pressed": self.buttons_pressed,
            "gripper_opening": self.gripper_opening,
            "object_positions": &self.object_positions[..3 * count],
        })
    }
}

impl ToJson for msgs::DriverStatus {
    fn to_json(&self) -> Value {
        json!({
            "seq": self.header.seq,
            "mode": code_name::<msgs::DriverMode>(self.mode),
            "hardware_ready": self.hardware_ready,
            "commands_received": self.commands_received,
            "limit_violations": self.limit_violations,
            "stale_cycles": self.stale_cycles,
            "safe_stop_cycles": self.safe_stop_cycles,
            "output_violations": self.output_violations,
            "max_command_gap_ms": self.max_command_gap_ns as f64 / 1e6,
            "resolver_id": self.resolver_id,
            "resolver_takeovers": self.resolver_takeovers,
            "max_takeover_interval_ms": self.max_takeover_interval_ns as f64 / 1e6,
        })
    }
}

/// A jsonschema (draft 2020-12 subset: `type`, `properties`, `required`, `items`) describing
/// `value`. Every message of a channel has the same fields, so each object lists all of its
/// properties as `required`.
pub fn schema_of(value: &Value) -> Value {
    match value {
        Value::Null => json!({ "type": "null" }),
        Value::Bool(_) => json!({ "type": "boolean" }),
        Value::Number(_) => json!({ "type": "number" }),
        Value::String(_) => json!({ "type": "string" }),
        Value::Array(items) => match items.first() {
            Some(first) => json!({ "type": "array", "items": schema_of(first) }),
            None => json!({ "type": "array" }),
        },
        Value::Object(fields) => {
            let properties: serde_json::Map<String, Value> = fields
                .iter()
                .map(|(k, v)| (k.clone(), schema_of(v)))
                .collect();
            let required: Vec<&String> = fields.keys().collect();
            json!({ "type": "object", "properties": properties, "required": required })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::Message;

    #[test]
    fn joint_state_json_keeps_only_the_used_joints_and_its_schema_describes_it() {
        let mut state = msgs::JointState::zeroed();
        state.joint_count = 2;
        state.position[..3].copy_from_slice(&[0.5, -0.25, 9.0]);
        let value = state.to_json();
        assert_eq!(value["position"], json!([0.5, -0.25]));
        let schema = schema_of(&value);
        assert_eq!(schema["type"], "object");
        assert_eq!(schema["properties"]["position"]["type"], "array");
        assert_eq!(schema["properties"]["position"]["items"]["type"], "number");
        let required: Vec<&str> = schema["required"]
            .as_array()
            .expect("required is listed")
            .iter()
            .map(|k| k.as_str().unwrap())
            .collect();
        let keys: Vec<&str> = value
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        assert_eq!(required, keys);
        assert!(required.contains(&"position"));
    }

    #[test]
    fn nested_objects_list_their_own_required_fields() {
        let schema = schema_of(&json!({ "a": 1, "rows": [{ "name": "x", "pid": 2 }] }));
        assert_eq!(schema["required"], json!(["a", "rows"]));
        assert_eq!(
            schema["properties"]["rows"]["items"]["required"],
            json!(["name", "pid"])
        );
        assert_eq!(schema_of(&json!({}))["required"], json!([]));
    }

    #[test]
    fn codes_are_named_and_bad_codes_are_unknown() {
        let mut stop = msgs::SafeStop::zeroed();
        stop.active = 1;
        stop.reason = msgs::SafeStopReason::DeadlineMiss as u32;
        assert_eq!(stop.to_json()["reason"], "DeadlineMiss");
        stop.reason = 77;
        assert_eq!(stop.to_json()["reason"], "unknown");
    }

    #[test]
    fn the_supervisor_table_lists_only_its_used_rows_with_named_states() {
        let mut status = msgs::SupervisorStatus::zeroed();
        status.process_count = 2;
        status.processes[0].set_name("qp-resolver");
        status.processes[0].state = msgs::SupervisedState::Running as u32;
        status.processes[1].set_name("watchdog");
        status.processes[1].state = msgs::SupervisedState::Restarting as u32;
        status.processes[1].restarts = 3;
        status.processes[2].set_name("not-in-use");
        let value = status.to_json();
        let rows = value["processes"].as_array().unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0]["name"], "qp-resolver");
        assert_eq!(rows[0]["state"], "Running");
        assert_eq!(rows[1]["state"], "Restarting");
        assert_eq!(rows[1]["restarts"], 3);
        assert_eq!(value["shutting_down"], false);
    }
}
