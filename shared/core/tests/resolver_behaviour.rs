//! Behaviour of the redundancy-resolution QP on Frankie: equality met when feasible, bounds
//! never exceeded, the damper keeps joints inside their limits, invalid input gives zeros, and
//! the base tracks the base controller's (v, ω), and a held joint (Fetch's torso) stays at its
//! ready position.

use std::path::Path;

use motm_core::qp_scenario::{QpScenario, ScenarioConfig};
use motm_core::resolver::margined_velocity_limits;
use motm_core::{
    BASE_JOINTS, BasePose, BaseVelocity, Facing, RedundancyResolver, ResolveStatus, ResolverConfig,
    Robot, Twist,
};
use nalgebra::DVector;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn frankie() -> Robot {
    let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    Robot::load(&config_dir, "frankie").expect("frankie model")
}

fn achieved(scenario_jacobian: &nalgebra::Matrix6xX<f64>, qd: &DVector<f64>) -> Twist {
    (scenario_jacobian * qd).fixed_rows::<6>(0).into_owned()
}

#[test]
fn feasible_twists_are_met_exactly_with_negligible_slack() {
    let robot = frankie();
    // Only the joint weights compete with the slack: no manipulability or facing term (those
    // trade slack for manipulability at a rate proportional to e_t, by design).
    let resolver_config = ResolverConfig {
        manipulability_gain: 0.0,
        ..ResolverConfig::default()
    };
    let mut resolver = RedundancyResolver::for_robot(&robot, resolver_config);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // Joints ≥ 0.9 rad from every limit (damper inactive) and q̇₀ within 30 % of the limits, so
    // q̇₀ itself is feasible with δ = 0.
    let config = ScenarioConfig {
        limit_clearance: 0.9,
        velocity_fraction: 0.3,
        base_tracking: false,
    };
    for i in 0..300 {
        let drawn = QpScenario::random(&robot, &config, &mut rng);
        // A twist the arm alone can produce (the base part of q̇₀ is zero, since the base weight
        // Y/e_t grows with the slack weight 1/e_t), at the e_t floor where the slack weight
        // 1/e_t = 1000 dominates the arm weight Y = 0.01.
        let mut arm_only = drawn.joint_velocity.clone();
        arm_only.rows_mut(0, BASE_JOINTS).fill(0.0);
        let mut scenario = QpScenario::at(&robot, drawn.base, drawn.arm_q, arm_only, 1e-3, false);
        scenario.facing = Facing::None;
        let out = resolver.resolve(&scenario.input());
        assert!(out.status.is_ok(), "scenario {i}: {:?}", out.status);
        let qd = out.joint_velocities();
        let residual = scenario.twist - achieved(&scenario.jacobian, &qd);
        // The equality J q̇ + δ = ν always holds…
        assert!((residual - out.slack).norm() < 1e-6, "scenario {i}");
        // …and the slack is negligible when the twist is reachable.
        assert!(
            out.slack.norm() < 1e-3 * scenario.twist.norm(),
            "scenario {i}: slack {} for |ν| {}",
            out.slack.norm(),
            scenario.twist.norm()
        );
    }
    assert_eq!(resolver.error_count(), 0);
}

#[test]
fn output_never_exceeds_a_bound_on_random_problems() {
    let robot = frankie();
    let config = ResolverConfig::default();
    let mut resolver = RedundancyResolver::for_robot(&robot, config.clone());
    let velocity_limits = margined_velocity_limits(&robot.limits(), &config);
    let limits = robot.limits();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let scenario_config = ScenarioConfig {
        limit_clearance: 0.0,
        velocity_fraction: 1.0,
        base_tracking: false,
    };
    let mut saturated = 0;
    for i in 0..500 {
        let mut scenario = QpScenario::random(&robot, &scenario_config, &mut rng);
        // Often unreachable: up to 3 m/s and 3 rad/s per axis.
        scenario.twist = Twist::from_fn(|_, _| rng.random_range(-3.0..3.0));
        scenario.position_error = rng.random_range(0.0..3.0);
        if rng.random_bool(0.5) {
            scenario.base_velocity_target = Some(BaseVelocity {
                v: rng.random_range(-2.0..2.0),
                omega: rng.random_range(-2.0..2.0),
            });
        }
        let out = resolver.resolve(&scenario.input());
        assert!(out.status.is_ok(), "scenario {i}: {:?}", out.status);
        let qd = out.joint_velocities();
        let (lower, upper) = resolver.last_bounds();
        for j in 0..qd.len() {
            assert!(
                qd[j].abs() <= velocity_limits[j],
                "scenario {i} joint {j}: {}",
                qd[j]
            );
            assert!(
                qd[j] >= lower[j] && qd[j] <= upper[j],
                "scenario {i} joint {j} damper"
            );
            if qd[j].abs() > 0.999 * velocity_limits[j] {
                saturated += 1;
            }
        }
        // The base limits come from the model without margins.
        assert!(out.base.omega.abs() <= limits[0].velocity);
        assert!(out.base.v.abs() <= limits[1].velocity);
        assert!(out.slack.iter().all(|d| d.abs() <= config.slack_bound));
    }
    assert!(
        saturated > 0,
        "the random problems must push some joint to its bound"
    );
    assert_eq!(resolver.error_count(), 0);
}

#[test]
fn damper_keeps_every_joint_inside_its_limits_over_a_long_random_run() {
    const DT: f64 = 0.025;
    const STEPS: usize = 4000;
    let robot = frankie();
    let limits = robot.limits();
    let mut resolver = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut arm_q = robot.config.ready_pose.clone();
    let base = BasePose::default();
    let mut twist = Twist::zeros();
    let mut closest = f64::INFINITY;
    for step in 0..STEPS {
        // A new random twist every second, held so the joints are driven into their limits.
        if step % 40 == 0 {
            twist = Twist::from_fn(|r, _| {
                let scale = if r < 3 { 0.6 } else { 1.5 };
                rng.random_range(-scale..scale)
            });
        }
        // The base is told to stand still, so the arm must absorb the twist.
        let out = resolver.resolve_motm(
            &robot,
            &base,
            &arm_q,
            twist,
            0.5,
            Some(BaseVelocity::default()),
        );
        assert!(out.status.is_ok(), "step {step}: {:?}", out.status);
        for (k, (q, qd)) in arm_q.iter_mut().zip(&out.arm_qd).enumerate() {
            *q += qd * DT;
            let l = &limits[BASE_JOINTS + k];
            assert!(
                *q > l.position_min && *q < l.position_max,
                "step {step}: joint {k} at {q} outside [{}, {}]",
                l.position_min,
                l.position_max
            );
            closest = closest.min((*q - l.position_min).min(l.position_max - *q));
        }
    }
    eprintln!("closest approach to a joint limit: {closest:.4} rad");
    // The run must actually bring a joint well inside the damper's influence zone.
    assert!(closest < 0.3, "closest approach {closest}");
    assert_eq!(resolver.error_count(), 0);
}

#[test]
fn non_finite_input_gives_zeros_and_counts_an_error_then_recovers() {
    let robot = frankie();
    let mut resolver = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let good = QpScenario::random(&robot, &ScenarioConfig::default(), &mut rng);
    let first = resolver.resolve(&good.input());
    assert!(first.status.is_ok());
    assert!(first.joint_velocities().norm() > 0.0);

    let mut bad = good.clone();
    bad.twist[2] = f64::NAN;
    let out = resolver.resolve(&bad.input());
    assert_eq!(out.status, ResolveStatus::InvalidInput);
    assert_eq!(out.base, BaseVelocity::default());
    assert!(out.arm_qd.iter().all(|v| *v == 0.0));
    assert_eq!(out.arm_qd.len(), robot.arm_dof());
    assert_eq!(resolver.error_count(), 1);

    let mut bad = good.clone();
    bad.jacobian[(0, 3)] = f64::INFINITY;
    assert_eq!(
        resolver.resolve(&bad.input()).status,
        ResolveStatus::InvalidInput
    );
    let mut bad = good.clone();
    bad.position_error = f64::NAN;
    assert_eq!(
        resolver.resolve(&bad.input()).status,
        ResolveStatus::InvalidInput
    );
    let mut bad = good.clone();
    bad.base_velocity_target = Some(BaseVelocity {
        v: f64::NAN,
        omega: 0.0,
    });
    assert_eq!(
        resolver.resolve(&bad.input()).status,
        ResolveStatus::InvalidInput
    );
    let mut bad = good.clone();
    bad.arm_q.pop();
    assert_eq!(
        resolver.resolve(&bad.input()).status,
        ResolveStatus::InvalidInput
    );
    let nan_q = vec![f64::NAN; robot.arm_dof()];
    let out = resolver.resolve_motm(
        &robot,
        &BasePose::default(),
        &nan_q,
        Twist::zeros(),
        0.1,
        None,
    );
    assert_eq!(out.status, ResolveStatus::InvalidInput);
    assert!(out.joint_velocities().iter().all(|v| *v == 0.0));
    assert_eq!(resolver.error_count(), 6);

    // The next valid cycle is solved afresh, identical to the first one.
    let again = resolver.resolve(&good.input());
    assert!(again.status.is_ok());
    assert!((again.joint_velocities() - first.joint_velocities()).norm() < 1e-9);
    assert_eq!(resolver.error_count(), 6);
}

#[test]
fn infeasible_problem_gives_zeros_and_counts_an_error() {
    let robot = frankie();
    let mut resolver = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut scenario = QpScenario::random(&robot, &ScenarioConfig::default(), &mut rng);
    // 1000 m/s cannot be met by joints plus slack bounded by 10.
    scenario.twist[0] = 1000.0;
    let out = resolver.resolve(&scenario.input());
    assert_eq!(out.status, ResolveStatus::SolverFailed);
    assert!(out.joint_velocities().iter().all(|v| *v == 0.0));
    assert!(out.slack.iter().all(|v| *v == 0.0));
    assert_eq!(resolver.error_count(), 1);
}

#[test]
fn base_follows_the_requested_velocity_when_the_arm_can_absorb_the_twist() {
    let robot = frankie();
    let mut tracking = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let mut free = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let requests = [(0.3, 0.0), (0.4, 0.2), (0.2, -0.3), (0.0, 0.4)];
    for (i, &(v, omega)) in requests.iter().enumerate() {
        let target = BaseVelocity { v, omega };
        let base = BasePose::new(
            rng.random_range(-2.0..2.0),
            0.0,
            rng.random_range(-1.0..1.0),
        );
        // Elbow (joint 4) 1.2 rad from its limit, so the damper leaves the arm room to retract.
        let arm_q = vec![0.0, -0.3, 0.0, -1.9, 0.0, 1.7, std::f64::consts::FRAC_PI_4];
        // The tool holds still in the world (ν = 0) while the base moves: the arm absorbs it.
        let twist = Twist::zeros();
        let e_t = 0.01;
        let out = tracking.resolve_motm(&robot, &base, &arm_q, twist, e_t, Some(target));
        assert!(out.status.is_ok());
        assert!(
            (out.base.v - v).abs() < 0.02,
            "request {i}: v {} vs {v}",
            out.base.v
        );
        assert!(
            (out.base.omega - omega).abs() < 0.02,
            "request {i}: ω {} vs {omega}",
            out.base.omega
        );
        let fk = robot.forward(&base, &arm_q);
        let err = achieved(&fk.jacobian, &out.joint_velocities()).norm();
        assert!(err < 1e-2, "request {i}: |J q̇ − ν| = {err}");
        // Without the tracking rows the base does not move on its own.
        let idle = free.resolve_motm(&robot, &base, &arm_q, twist, e_t, None);
        let idle_gap = (idle.base.v - v).abs().max((idle.base.omega - omega).abs());
        assert!(
            idle_gap > 0.1,
            "request {i}: the base moves like this without tracking"
        );
    }
}

#[test]
fn facing_term_turns_arm_joint_1_toward_the_gripper() {
    let robot = frankie();
    let mut resolver = RedundancyResolver::for_robot(&robot, ResolverConfig::default());
    let base = BasePose::default();
    for (i, &(q1, q3)) in [(0.0, 0.6), (0.0, -0.6), (0.4, -0.8)].iter().enumerate() {
        // Joint 3 swings the gripper sideways, away from where joint 1 points.
        let arm_q = vec![q1, -0.3, q3, -2.0, 0.0, 2.0, std::f64::consts::FRAC_PI_4];
        let scenario = QpScenario::at(
            &robot,
            base,
            arm_q.clone(),
            DVector::zeros(robot.limits().len()),
            0.2,
            false,
        );
        let Facing::ArmJoint1 { tool_in_arm_base } = scenario.facing else {
            panic!("MotM scenarios face arm joint 1");
        };
        let offset = tool_in_arm_base.y.atan2(tool_in_arm_base.x) - q1;
        assert!(
            offset.abs() > 0.05,
            "case {i}: the gripper must be off joint 1's heading"
        );
        let with = resolver.resolve(&scenario.input());
        let mut without_input = scenario.input();
        without_input.facing = Facing::None;
        let without = resolver.resolve(&without_input);
        let push = with.arm_qd[0] - without.arm_qd[0];
        assert!(
            push * offset > 0.0,
            "case {i}: joint 1 pushed by {push} for an offset of {offset}"
        );
    }
}

#[test]
fn config_reads_from_toml_with_defaults_and_rejects_unknown_keys() {
    let config: ResolverConfig = toml::from_str("facing_gain = 0.8").expect("valid");
    assert_eq!(config.facing_gain, 0.8);
    assert_eq!(config.damper_influence_distance, 0.9);
    let err = toml::from_str::<ResolverConfig>("facing_gian = 0.8").unwrap_err();
    assert!(err.to_string().contains("facing_gian"), "{err}");
}

#[test]
fn a_held_joint_is_servoed_to_its_ready_position_while_the_others_move_the_tool() {
    let config_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let fetch = Robot::load(&config_dir, "fetch").expect("fetch model");
    assert_eq!(
        fetch.held_joints(),
        vec![(0, 0.0)],
        "Fetch holds its torso down"
    );
    let mut free_fetch = fetch.clone();
    free_fetch.config.held_joints.clear();
    let base = BasePose::new(1.0, -0.5, 0.3);
    // The tool rises at 0.1 m/s.
    let twist = Twist::new(0.0, 0.0, 0.1, 0.0, 0.0, 0.0);
    let e_t = 0.05;
    for torso in [0.0, 0.2] {
        let mut arm_q = fetch.config.ready_pose.clone();
        arm_q[0] = torso;
        let mut held = RedundancyResolver::for_robot(&fetch, ResolverConfig::default());
        let out = held.resolve_motm(&fetch, &base, &arm_q, twist, e_t, None);
        assert!(out.status.is_ok());
        let fk = fetch.forward(&base, &arm_q);
        let err = (achieved(&fk.jacobian, &out.joint_velocities()) - twist).norm();
        assert!(err < 1e-2, "torso {torso}: |J q̇ − ν| = {err}");
        // The servo's rate (1/s) times the distance to rest, within the torso's speed limit.
        let limit =
            margined_velocity_limits(&fetch.limits(), &ResolverConfig::default())[BASE_JOINTS];
        let toward_rest = (-torso).max(-limit);
        assert!(
            (out.arm_qd[0] - toward_rest).abs() < 0.01,
            "torso {torso}: q̇ {} instead of {toward_rest}",
            out.arm_qd[0]
        );
        if torso == 0.0 {
            // Left free, the torso at its lower limit (the ready pose's) is pushed up by the
            // joint-limit damper, and the tool's rise is done by it.
            let mut free = RedundancyResolver::for_robot(&free_fetch, ResolverConfig::default());
            let loose = free.resolve_motm(&free_fetch, &base, &arm_q, twist, e_t, None);
            assert!(
                loose.arm_qd[0] > 0.05,
                "a free torso would rise ({})",
                loose.arm_qd[0]
            );
        }
    }
}
