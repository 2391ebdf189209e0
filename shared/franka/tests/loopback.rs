//! The FCI and hand clients against the fake robot's server code, on real loopback TCP and
//! UDP sockets: the fake runs at 1 kHz in a thread, the client in the test thread. Loops are
//! bounded by the number of states received, never by wall-clock time.

use std::io::{Read, Write};
use std::net::{IpAddr, Ipv4Addr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use motm_franka::fake::{
    DropPlan, FakeHand, FakeHandConfig, FakeRobot, FakeRobotConfig, IdealArm, IdealHand,
    run_every_ms,
};
use motm_franka::fci::{MoveStatus, RecoveryStatus, StopMoveStatus};
use motm_franka::hand::{HandClient, HandCommand, HandConfig, HandStatus};
use motm_franka::state::RobotMode;
use motm_franka::{
    FciClient, FciConfig, FciError, Motion, MotionEnd, ProtocolError, SafeStopCause,
};

const LOCALHOST: IpAddr = IpAddr::V4(Ipv4Addr::LOCALHOST);

/// A fake robot and hand running at 1 kHz in a thread.
struct Fake {
    port: u16,
    hand_port: u16,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<(FakeRobot, FakeHand, IdealArm)>>,
}

impl Fake {
    fn start(config: FakeRobotConfig) -> Self {
        let mut robot = FakeRobot::bind(LOCALHOST, 0, config).unwrap();
        let mut hand = FakeHand::bind(LOCALHOST, 0, FakeHandConfig::default()).unwrap();
        let (port, hand_port) = (robot.port(), hand.port());
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut arm = IdealArm::default();
            let mut fingers = IdealHand::new(0.08, Some(0.03));
            run_every_ms(|| {
                robot.cycle(&mut arm);
                hand.cycle(&mut fingers);
                !flag.load(Ordering::Relaxed)
            });
            (robot, hand, arm)
        });
        Self {
            port,
            hand_port,
            stop,
            thread: Some(thread),
        }
    }

    fn client(&self) -> FciClient {
        FciClient::connect(
            LOCALHOST,
            FciConfig {
                port: self.port,
                ..FciConfig::default()
            },
        )
        .unwrap()
    }

    fn finish(mut self) -> (FakeRobot, FakeHand, IdealArm) {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().unwrap()
    }
}

impl Drop for Fake {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Reads states until the first one.
fn first_state(client: &mut FciClient) {
    while !client.has_state() {
        client.next_state().unwrap();
    }
}

/// Starts a motion and steps (commanding `dq`) until it runs; returns the robot time then.
fn start_running(client: &mut FciClient, dq: [f64; 7]) -> u64 {
    first_state(client);
    client.start_motion().unwrap();
    for _ in 0..2000 {
        assert_eq!(client.next_state().unwrap(), None);
        if client.running() {
            return client.state().message_id;
        }
        // Nothing is sent before the motion runs.
        assert_eq!(client.command(&dq).unwrap(), None);
    }
    panic!("the motion never started: {:?}", client.motion());
}

/// Steps `cycles` states commanding `dq`, returning the end if the motion ended.
fn run(client: &mut FciClient, dq: [f64; 7], cycles: usize) -> Option<MotionEnd> {
    for _ in 0..cycles {
        if let Some(end) = client.next_state().unwrap() {
            return Some(end);
        }
        client.command(&dq).unwrap();
    }
    None
}

/// Finishes the motion and steps until it ends.
fn finish(client: &mut FciClient) -> MotionEnd {
    client.finish();
    run(client, [0.0; 7], 5000).expect("the motion should end")
}

#[test]
fn a_full_move_lifecycle_runs_within_the_limits() {
    let fake = Fake::start(FakeRobotConfig::default());
    let mut client = fake.client();
    let dq = [0.5, -0.5, 0.3, -0.3, 1.0, -1.0, 0.2];
    start_running(&mut client, dq);
    assert_eq!(run(&mut client, dq, 1000), None);
    let s = *client.state();
    for (i, want) in dq.iter().enumerate() {
        assert!((s.dq[i] - want).abs() < 1e-3, "joint {i}: {}", s.dq[i]);
        assert_eq!(s.dq[i], s.dq_d[i], "the ideal arm follows the command");
    }
    assert!(s.control_command_success_rate > 0.5);
    assert_eq!(
        finish(&mut client),
        MotionEnd::Finished(SafeStopCause::Requested)
    );
    assert_eq!(client.motion(), Motion::Idle);
    // The robot is idle and at rest; the joint state is the robot's.
    client.next_state().unwrap();
    assert!(client.state().idle());
    assert!(client.joints().1.iter().all(|v| v.abs() < 1e-3));
    let c = client.counters();
    assert!(c.commands_sent > 1000);
    assert_eq!((c.motions, c.reflexes, c.bad_datagrams), (1, 0, 0));
    drop(client);
    let (robot, _, arm) = fake.finish();
    let rc = robot.counters();
    assert_eq!((rc.motions, rc.finished, rc.reflexes), (1, 1, 0));
    assert_eq!(rc.violations.commands, 0, "{}", robot.summary());
    assert!(arm.q[4] > 0.5, "the arm moved: {:?}", arm.q);
}

#[test]
fn twenty_five_dropped_commands_raise_a_reflex_that_becomes_a_safe_stop() {
    let fake = Fake::start(FakeRobotConfig {
        drop: Some(DropPlan {
            at_ms: 1500,
            count: 25,
        }),
        ..FakeRobotConfig::default()
    });
    let mut client = fake.client();
    let dq = [0.2; 7];
    let started = start_running(&mut client, dq);
    assert!(
        started < 1400,
        "the motion must run before the drop ({started})"
    );
    let end = run(&mut client, dq, 5000).expect("the reflex ends the motion");
    assert_eq!(
        end,
        MotionEnd::Reflex {
            reasons: vec![25],
            status: Some(MoveStatus::ReflexAborted)
        }
    );
    assert!(end.communication_constraints_violation());
    assert!(
        end.describe()
            .contains("communication_constraints_violation")
    );
    assert_eq!(client.last_end(), Some(&end));
    assert!(client.state().in_reflex());
    assert!(client.state().errors[25] && client.state().reflex_reason[25]);
    assert_eq!(client.counters().reflexes, 1);
    // No automatic recovery: a new motion is refused until the user recovers.
    for _ in 0..50 {
        client.next_state().unwrap();
        assert_eq!(
            client.command(&dq).unwrap(),
            None,
            "no command after the reflex"
        );
    }
    assert!(
        client.state().in_reflex(),
        "the client never recovers on its own"
    );
    assert!(matches!(
        client.start_motion(),
        Err(FciError::NotPossible(_))
    ));
    client.request_error_recovery().unwrap();
    for _ in 0..1000 {
        client.next_state().unwrap();
        if client.recovery().is_some() && client.state().idle() {
            break;
        }
    }
    assert_eq!(client.recovery(), Some(RecoveryStatus::Success));
    start_running(&mut client, dq);
    run(&mut client, dq, 100);
    assert_eq!(
        finish(&mut client),
        MotionEnd::Finished(SafeStopCause::Requested)
    );
    drop(client);
    let (robot, _, _) = fake.finish();
    let rc = robot.counters();
    assert_eq!(rc.reflexes, 1);
    // The reflex comes at the 20th consecutive missed cycle: at most 20 of the 25 planned
    // drops happen (fewer if a late command of the client's own started the run).
    assert_eq!(rc.max_consecutive_missed, 20);
    assert!((15..=20).contains(&rc.dropped), "{}", robot.summary());
    assert_eq!((rc.recoveries, rc.motions, rc.finished), (1, 2, 1));
    assert_eq!(rc.violations.commands, 0, "{}", robot.summary());
}

#[test]
fn a_new_client_reconnects_after_the_old_one_is_dropped() {
    let fake = Fake::start(FakeRobotConfig::default());
    let mut first = fake.client();
    start_running(&mut first, [0.3; 7]);
    run(&mut first, [0.3; 7], 200);
    drop(first);
    let mut second = fake.client();
    first_state(&mut second);
    // The fake stopped the orphaned motion: idle, so a new one starts.
    for _ in 0..100 {
        second.next_state().unwrap();
        if second.state().idle() {
            break;
        }
    }
    start_running(&mut second, [0.3; 7]);
    run(&mut second, [0.3; 7], 200);
    assert_eq!(
        finish(&mut second),
        MotionEnd::Finished(SafeStopCause::Requested)
    );
    drop(second);
    let (robot, _, _) = fake.finish();
    let rc = robot.counters();
    assert_eq!((rc.connections, rc.motions, rc.finished), (2, 2, 1));
}

#[test]
fn a_wrong_size_datagram_is_an_error_a_count_and_a_safe_stop_never_a_command() {
    let fake = Fake::start(FakeRobotConfig {
        bad_state_at_ms: Some(1200),
        ..FakeRobotConfig::default()
    });
    let mut client = fake.client();
    let started = start_running(&mut client, [0.4; 7]);
    assert!(started < 1100);
    let end = run(&mut client, [0.4; 7], 5000).expect("the safe stop ends the motion");
    let wrong = ProtocolError::WrongSize {
        message: "RobotState",
        expected: 2373,
        got: 2372,
    };
    assert_eq!(
        end,
        MotionEnd::Finished(SafeStopCause::BadDatagram(wrong.clone()))
    );
    assert_eq!(client.last_error(), Some(&wrong));
    let c = client.counters();
    assert_eq!((c.bad_datagrams, c.safe_stops), (1, 1));
    assert!(c.lost_states >= 1, "the bad state is a gap in message_id");
    drop(client);
    let (robot, _, _) = fake.finish();
    let rc = robot.counters();
    assert!(rc.missed_cycles >= 1, "the bad state was never answered");
    assert_eq!(
        rc.violations.commands, 0,
        "the ramp stays within the limits"
    );
    assert_eq!((rc.finished, rc.reflexes), (1, 0));
}

#[test]
fn stop_move_cancels_the_motion() {
    let fake = Fake::start(FakeRobotConfig::default());
    let mut client = fake.client();
    start_running(&mut client, [0.1; 7]);
    run(&mut client, [0.1; 7], 100);
    client.cancel().unwrap();
    let end = run(&mut client, [0.1; 7], 2000).expect("cancelled");
    assert_eq!(end, MotionEnd::Cancelled(StopMoveStatus::Success));
    drop(client);
    let (robot, _, _) = fake.finish();
    assert_eq!(robot.counters().cancelled, 1);
}

#[test]
fn a_dropped_connection_is_a_fatal_error() {
    let fake = Fake::start(FakeRobotConfig::default());
    let mut client = fake.client();
    start_running(&mut client, [0.1; 7]);
    let (robot, hand, _) = fake.finish();
    drop((robot, hand));
    let mut error = None;
    for _ in 0..200 {
        match client.next_state() {
            Ok(_) => {
                client.command(&[0.1; 7]).ok();
            }
            Err(e) => {
                error = Some(e);
                break;
            }
        }
    }
    assert!(
        matches!(error, Some(FciError::ConnectionLost(_))),
        "{error:?}"
    );
}

#[test]
fn an_incompatible_version_is_refused_both_ways() {
    // The client against a robot that speaks version 6.
    let listener = TcpListener::bind((LOCALHOST, 0)).unwrap();
    let port = listener.local_addr().unwrap().port();
    let server = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        let mut req = [0u8; 16];
        s.read_exact(&mut req).unwrap();
        // command 0, the request's id, size 15, status 1 (incompatible), version 6.
        let mut resp = vec![0, 0, 0, 0];
        resp.extend_from_slice(&req[4..8]);
        resp.extend_from_slice(&[15, 0, 0, 0, 1, 6, 0]);
        s.write_all(&resp).unwrap();
    });
    let err = FciClient::connect(
        LOCALHOST,
        FciConfig {
            port,
            ..FciConfig::default()
        },
    )
    .err()
    .unwrap();
    assert_eq!(
        err,
        FciError::Protocol(ProtocolError::IncompatibleVersion {
            message: "Connect response",
            ours: 5,
            theirs: 6
        })
    );
    server.join().unwrap();
    // The fake against a client that speaks version 4: refused, then closed.
    let fake = Fake::start(FakeRobotConfig::default());
    let mut s = TcpStream::connect((LOCALHOST, fake.port)).unwrap();
    s.write_all(&[0, 0, 0, 0, 0, 0, 0, 0, 16, 0, 0, 0, 4, 0, 1, 0])
        .unwrap();
    let mut resp = Vec::new();
    s.read_to_end(&mut resp).unwrap();
    assert_eq!(resp, [0, 0, 0, 0, 0, 0, 0, 0, 15, 0, 0, 0, 1, 5, 0]);
    // An unknown command number: counted, and the connection closed without an answer.
    let mut s = TcpStream::connect((LOCALHOST, fake.port)).unwrap();
    s.write_all(&[99, 0, 0, 0, 0, 0, 0, 0, 12, 0, 0, 0])
        .unwrap();
    let mut resp = Vec::new();
    s.read_to_end(&mut resp).unwrap();
    assert!(resp.is_empty());
    let (robot, _, _) = fake.finish();
    assert_eq!(robot.counters().protocol_errors, 1);
    assert_eq!(robot.robot_mode(), RobotMode::Idle);
}

#[test]
fn the_hand_grasps_and_opens() {
    let fake = Fake::start(FakeRobotConfig::default());
    let mut hand = HandClient::connect(
        LOCALHOST,
        HandConfig {
            port: fake.hand_port,
            ..HandConfig::default()
        },
    )
    .unwrap();
    let close = hand.close_request();
    let open = hand.open_request();
    // Polls until the last result differs from `before` (bounded by the number of polls).
    let wait_result = |hand: &mut HandClient, before| {
        for _ in 0..100_000 {
            hand.poll().unwrap();
            if hand.last_result() != before && !hand.busy() {
                return hand.last_result();
            }
            std::thread::sleep(std::time::Duration::from_micros(100));
        }
        None
    };
    let wait_state =
        |hand: &mut HandClient, want: &dyn Fn(&motm_franka::hand::GripperState) -> bool| {
            for _ in 0..100_000 {
                if let Some(s) = hand.poll().unwrap()
                    && want(&s)
                {
                    return Some(s);
                }
                std::thread::sleep(std::time::Duration::from_micros(100));
            }
            None
        };
    hand.request(close).unwrap();
    assert!(hand.busy());
    let r = wait_result(&mut hand, None);
    assert_eq!(r, Some((HandCommand::Grasp, HandStatus::Success)));
    let g = wait_state(&mut hand, &|s| s.is_grasped).expect("a state shows the grasp");
    assert!((g.width - 0.03).abs() < 1e-9, "{g:?}");
    assert_eq!(g.max_width, 0.08);
    // Open; while it runs, a Close then an Open are queued: the newest wins.
    hand.request(open).unwrap();
    hand.request(close).unwrap();
    hand.request(open).unwrap();
    assert_eq!(
        (hand.counters().requests, hand.counters().superseded),
        (2, 1)
    );
    let r = wait_result(&mut hand, r);
    assert_eq!(r, Some((HandCommand::Move, HandStatus::Success)));
    let s = wait_state(&mut hand, &|s| s.width > 0.08 - 1e-9).expect("opened");
    // The queued Open goes out when the first is answered, and succeeds at once.
    for _ in 0..100_000 {
        hand.poll().unwrap();
        if hand.counters().requests == 3 && !hand.busy() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_micros(100));
    }
    assert_eq!(hand.counters().requests, 3);
    assert!(!s.is_grasped, "{s:?}");
    drop(hand);
    let (_, fake_hand, _) = fake.finish();
    let hc = fake_hand.counters();
    assert_eq!((hc.actions, hc.succeeded, hc.failed), (3, 3, 0));
}
