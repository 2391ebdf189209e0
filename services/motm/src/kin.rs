//! `motm kin`: forward kinematics, Jacobian and manipulability of a robot model.

use std::path::Path;

use clap::Args;
use motm_core::{BasePose, Robot, manipulability};
use serde_json::json;

/// Arguments of `motm kin`.
#[derive(Args)]
pub struct KinArgs {
    /// Robot name: frankie, fetch or husky_ur5.
    #[arg(long)]
    robot: String,
    /// Base pose in the world frame as X,Y,YAW (m, m, rad).
    #[arg(long, allow_hyphen_values = true, default_value = "0,0,0")]
    base: NumberList,
    /// Arm joint positions, comma separated (default: the robot's ready pose).
    #[arg(long, allow_hyphen_values = true)]
    q: Option<NumberList>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// A comma-separated list of finite numbers, e.g. `0,-0.3,0`.
#[derive(Debug, Clone)]
pub struct NumberList(pub Vec<f64>);

impl std::str::FromStr for NumberList {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        s.split(',')
            .map(|v| {
                let v = v.trim();
                v.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| format!("'{v}' is not a finite number"))
            })
            .collect::<Result<_, _>>()
            .map(NumberList)
    }
}

/// Runs `motm kin`.
pub fn run(config_dir: &Path, args: &KinArgs) -> Result<(), String> {
    let robot = Robot::load(config_dir, &args.robot).map_err(|e| e.to_string())?;
    let [x, y, yaw] = args.base.0[..] else {
        return Err(format!(
            "--base: expected X,Y,YAW, got {} values",
            args.base.0.len()
        ));
    };
    let q = args
        .q
        .clone()
        .map(|l| l.0)
        .unwrap_or_else(|| robot.config.ready_pose.clone());
    if q.len() != robot.arm_dof() {
        return Err(format!(
            "--q: {} has {} arm joints, got {} values",
            robot.name(),
            robot.arm_dof(),
            q.len()
        ));
    }
    let fk = robot.forward(&BasePose::new(x, y, yaw), &q);
    let m = manipulability(&Robot::arm_jacobian(&fk.jacobian));
    let p = fk.tool_pose.translation.vector;
    let r = fk.tool_pose.rotation.to_rotation_matrix();
    let rows = |rows: usize, cols: usize, at: &dyn Fn(usize, usize) -> f64| -> Vec<Vec<f64>> {
        (0..rows)
            .map(|i| (0..cols).map(|j| at(i, j)).collect())
            .collect()
    };
    let rotation = rows(3, 3, &|i, j| r[(i, j)]);
    let jacobian = rows(6, fk.jacobian.ncols(), &|i, j| fk.jacobian[(i, j)]);
    if args.json {
        let out = json!({
            "robot": robot.name(),
            "position": [p.x, p.y, p.z],
            "rotation": rotation,
            "jacobian": jacobian,
            "manipulability": m,
        });
        println!("{out}");
        return Ok(());
    }
    let names: Vec<&str> = robot.chain.joints.iter().map(|j| j.name.as_str()).collect();
    println!("robot          {}", robot.name());
    println!("base pose      x={x:.4} m  y={y:.4} m  yaw={yaw:.4} rad");
    println!("arm q          {q:?}");
    println!(
        "tool position  [{:.4}, {:.4}, {:.4}] m (world)",
        p.x, p.y, p.z
    );
    println!("tool rotation");
    for row in &rotation {
        println!("  [{:8.4} {:8.4} {:8.4}]", row[0], row[1], row[2]);
    }
    println!("manipulability {m:.5} (arm only, Yoshikawa)");
    println!("jacobian (world frame; rows vx vy vz wx wy wz)");
    println!(
        "  {}",
        names.iter().map(|n| format!("{n:>14}")).collect::<String>()
    );
    for (row, label) in jacobian.iter().zip(["vx", "vy", "vz", "wx", "wy", "wz"]) {
        let cells: String = row.iter().map(|v| format!("{v:>14.5}")).collect();
        println!("{label}{cells}");
    }
    Ok(())
}
