//! Commands of several controllers on one topic: during a hot swap the old and the new
//! final-phase controller publish side by side, and a consumer must use the active one's.
//! A plain latest value would hold whichever sample came last, so that the active
//! controller's command could be hidden behind the inactive one's for a cycle.
//! [`PerController`] keeps the newest command of each controller id instead.
//!
//! Likewise the QP resolver and its hot standby both publish joint and base commands, computed
//! from the same inputs in the same cycle; a driver follows one instance's stream and turns to
//! the other's when the one it follows stops ([`ResolverSelector`]).

use motm_msgs::{GripperCommand, Message, TwistCommand};

/// A command that names the controller that sent it.
pub trait FromController: Message + Copy {
    /// Id of the sending controller.
    fn controller_id(&self) -> u32;
}

impl FromController for TwistCommand {
    fn controller_id(&self) -> u32 {
        self.controller_id
    }
}

impl FromController for GripperCommand {
    fn controller_id(&self) -> u32 {
        self.controller_id
    }
}

/// Controllers remembered at once (old and new during a swap, plus restarts).
const TRACKED_CONTROLLERS: usize = 4;

/// Newest command per controller id.
#[derive(Debug, Clone)]
pub struct PerController<M: FromController> {
    /// `(controller id, newest command)`, most recently updated last.
    newest: Vec<(u32, M)>,
}

impl<M: FromController> Default for PerController<M> {
    fn default() -> Self {
        Self {
            newest: Vec::with_capacity(TRACKED_CONTROLLERS),
        }
    }
}

impl<M: FromController> PerController<M> {
    /// Takes in the commands of one cycle, oldest first.
    pub fn extend<'a>(&mut self, commands: impl IntoIterator<Item = &'a M>) {
        for command in commands {
            self.insert(*command);
        }
    }

    /// Records `command` as its controller's newest.
    pub fn insert(&mut self, command: M) {
        let id = command.controller_id();
        if let Some(i) = self.newest.iter().position(|(c, _)| *c == id) {
            self.newest.remove(i);
        } else if self.newest.len() == TRACKED_CONTROLLERS {
            self.newest.remove(0);
        }
        self.newest.push((id, command));
    }

    /// The newest command of controller `active`, or, while no controller is named active,
    /// the newest command of any controller.
    pub fn get(&self, active: Option<u32>) -> Option<&M> {
        match active {
            Some(id) => self.newest.iter().find(|(c, _)| *c == id).map(|(_, m)| m),
            None => self
                .newest
                .iter()
                .max_by_key(|(_, m)| m.header().stamp_ns)
                .map(|(_, m)| m),
        }
    }
}

/// Id of the primary QP resolver's commands.
pub const PRIMARY_RESOLVER_ID: u32 = 1;
/// Id of the hot-standby QP resolver's commands.
pub const STANDBY_RESOLVER_ID: u32 = 2;

/// Which resolver instance's commands a driver takes. Both instances run on the same twists'
/// arrival, so each cycle brings one command from each, stamped close together, in either
/// order. The selector follows one instance (the primary at first) and takes its commands at
/// once. Another instance's command is passed over when the followed one has already commanded
/// in that cycle (within half a period before it); otherwise it is held, and taken
/// ([`ResolverSelector::due`]) if the followed instance's command of that cycle has still not
/// come `wait_ns` after its stamp: the followed instance missed a cycle, and from then on the
/// selector follows the other (a takeover). A dead primary so costs its standby's command
/// `wait_ns` of delay, once. Until the followed instance has commanded at all, any instance's
/// command is taken at once (start-up, and the baselines' single stream, id 0).
#[derive(Debug, Clone)]
pub struct ResolverSelector {
    half_period_ns: u64,
    wait_ns: u64,
    following: u32,
    /// `(instance id, newest stamp)`.
    newest: Vec<(u32, u64)>,
    /// Another instance's command held: `(id, stamp, velocity)`.
    held: Option<(u32, u64, Vec<f64>)>,
    takeovers: u32,
    max_takeover_interval_ns: u64,
}

impl ResolverSelector {
    /// A selector for commands every `period_ns` that waits `wait_ns` for the followed
    /// instance before it takes another's command.
    pub fn new(period_ns: u64, wait_ns: u64) -> Self {
        Self {
            half_period_ns: period_ns / 2,
            wait_ns,
            following: PRIMARY_RESOLVER_ID,
            newest: Vec::with_capacity(TRACKED_CONTROLLERS),
            held: None,
            takeovers: 0,
            max_takeover_interval_ns: 0,
        }
    }

    /// Offers the command `velocity` of instance `id` stamped `stamp_ns` (call it for every
    /// command, in arrival order); returns whether to take it now.
    pub fn offer(&mut self, id: u32, stamp_ns: u64, velocity: &[f64]) -> bool {
        match self.newest.iter_mut().find(|(i, _)| *i == id) {
            Some((_, newest)) => *newest = (*newest).max(stamp_ns),
            None => {
                if self.newest.len() == TRACKED_CONTROLLERS {
                    self.newest.remove(0);
                }
                self.newest.push((id, stamp_ns));
            }
        }
        if id == self.following {
            // The followed instance's command covers a held one of the same cycle.
            if self
                .held
                .as_ref()
                .is_some_and(|&(_, held, _)| stamp_ns + self.half_period_ns >= held)
            {
                self.held = None;
            }
            return true;
        }
        let Some(followed) = self.newest_of(self.following) else {
            return true;
        };
        if followed + self.half_period_ns < stamp_ns {
            let mut buffer = self.held.take().map(|(_, _, v)| v).unwrap_or_default();
            buffer.clear();
            buffer.extend_from_slice(velocity);
            self.held = Some((id, stamp_ns, buffer));
        }
        false
    }

    /// At driver time `now_ns`: the held command, when the followed instance has missed its
    /// cycle for `wait_ns` (a takeover: the selector follows its sender from now on). A driver
    /// calls it every cycle, and before offering each command with that command's stamp as
    /// `now_ns` (so that one which reads many commands at once, the 50 Hz base driver, takes
    /// the held one first).
    pub fn due(&mut self, now_ns: u64) -> Option<(u64, Vec<f64>)> {
        let &(id, stamp, _) = self.held.as_ref()?;
        if now_ns < stamp.saturating_add(self.wait_ns) {
            return None;
        }
        let (_, _, velocity) = self.held.take()?;
        self.take_over(id, stamp);
        Some((stamp, velocity))
    }

    /// Follows `id` from its command stamped `stamp_ns` on.
    fn take_over(&mut self, id: u32, stamp_ns: u64) {
        if let Some(last) = self.newest_of(self.following) {
            self.max_takeover_interval_ns = self
                .max_takeover_interval_ns
                .max(stamp_ns.saturating_sub(last));
        }
        self.following = id;
        self.takeovers += 1;
    }

    /// The longest interval a takeover made: from the last command taken from the instance
    /// left to the first taken from the one followed, ns (about a period plus the wait).
    pub fn max_takeover_interval_ns(&self) -> u64 {
        self.max_takeover_interval_ns
    }

    fn newest_of(&self, id: u32) -> Option<u64> {
        self.newest.iter().find(|(i, _)| *i == id).map(|&(_, s)| s)
    }

    /// The instance followed.
    pub fn following(&self) -> u32 {
        self.following
    }

    /// Takeovers so far.
    pub fn takeovers(&self) -> u32 {
        self.takeovers
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_msgs::Header;

    fn twist(id: u32, stamp_ns: u64) -> TwistCommand {
        let mut m = TwistCommand::zeroed();
        m.controller_id = id;
        m.header = Header::new(stamp_ns, 0);
        m
    }

    #[test]
    fn the_active_controllers_command_is_kept_whoever_published_last() {
        let mut reader = PerController::<TwistCommand>::default();
        reader.extend(&[twist(2, 0), twist(1, 0)]);
        // The old controller published last; the new one's command is still there.
        assert_eq!(reader.get(Some(2)).unwrap().controller_id, 2);
        assert_eq!(reader.get(Some(1)).unwrap().controller_id, 1);
        assert_eq!(reader.get(None).unwrap().controller_id, 1);
        assert!(reader.get(Some(3)).is_none());
    }

    #[test]
    fn only_the_most_recent_controllers_are_remembered() {
        let mut reader = PerController::<TwistCommand>::default();
        for id in 1..=5 {
            reader.insert(twist(id, u64::from(id)));
        }
        assert!(reader.get(Some(1)).is_none());
        assert_eq!(reader.get(Some(5)).unwrap().controller_id, 5);
        reader.insert(twist(2, 9));
        assert_eq!(reader.get(None).unwrap().header.stamp_ns, 9);
    }

    const MS: u64 = 1_000_000;
    const V: &[f64] = &[0.1, 0.2];

    #[test]
    fn the_primary_is_followed_while_it_commands_and_the_standby_takes_over_when_it_stops() {
        let mut s = ResolverSelector::new(5 * MS, MS);
        assert!(s.offer(PRIMARY_RESOLVER_ID, 95 * MS, V));
        // Both instances command every 5 ms, the standby before or after the primary.
        for k in 0..10 {
            let t = 100 * MS + k * 5 * MS;
            if k % 2 == 0 {
                assert!(!s.offer(STANDBY_RESOLVER_ID, t - 300_000, V));
                assert!(s.offer(PRIMARY_RESOLVER_ID, t, V));
            } else {
                assert!(s.offer(PRIMARY_RESOLVER_ID, t, V));
                assert!(!s.offer(STANDBY_RESOLVER_ID, t + 300_000, V));
            }
            assert_eq!(s.due(t + 2 * MS), None);
        }
        assert_eq!(s.takeovers(), 0);
        // The primary's last command is at 145 ms; the standby's of the next cycle is held,
        // and taken once the primary has missed that cycle for 1 ms.
        assert!(!s.offer(STANDBY_RESOLVER_ID, 150 * MS, V));
        assert_eq!(s.due(150 * MS + 500_000), None);
        assert_eq!(s.due(151 * MS), Some((150 * MS, V.to_vec())));
        assert_eq!((s.following(), s.takeovers()), (STANDBY_RESOLVER_ID, 1));
        assert_eq!(s.max_takeover_interval_ns(), 5 * MS);
        assert!(s.offer(STANDBY_RESOLVER_ID, 155 * MS, V));
        // The restarted primary is now the standby: its commands are passed over.
        assert!(!s.offer(PRIMARY_RESOLVER_ID, 155 * MS + 200_000, V));
        assert_eq!(s.due(160 * MS), None);
        assert_eq!(s.takeovers(), 1);
    }

    #[test]
    fn a_driver_that_reads_seldom_takes_over_within_its_queue() {
        let mut s = ResolverSelector::new(5 * MS, MS);
        assert!(s.offer(PRIMARY_RESOLVER_ID, 100 * MS, V));
        // The primary dies; a 50 Hz driver reads three standby commands in one cycle: the
        // second's stamp already shows the primary missed the first one's cycle.
        assert_eq!(s.due(105 * MS), None);
        assert!(!s.offer(STANDBY_RESOLVER_ID, 105 * MS, V));
        assert_eq!(s.due(110 * MS), Some((105 * MS, V.to_vec())));
        assert!(s.offer(STANDBY_RESOLVER_ID, 110 * MS, V));
        assert_eq!(s.due(115 * MS), None);
        assert!(s.offer(STANDBY_RESOLVER_ID, 115 * MS, V));
        assert_eq!((s.following(), s.takeovers()), (STANDBY_RESOLVER_ID, 1));
        assert_eq!(s.max_takeover_interval_ns(), 5 * MS);
    }

    #[test]
    fn a_late_command_of_the_followed_instance_keeps_it_followed() {
        let mut s = ResolverSelector::new(5 * MS, MS);
        assert!(s.offer(PRIMARY_RESOLVER_ID, 100 * MS, V));
        // The standby's command of the next cycle comes first; the primary's 0.6 ms later.
        assert!(!s.offer(STANDBY_RESOLVER_ID, 105 * MS, V));
        assert!(s.offer(PRIMARY_RESOLVER_ID, 105 * MS + 600_000, V));
        assert_eq!(s.due(107 * MS), None);
        assert_eq!((s.following(), s.takeovers()), (PRIMARY_RESOLVER_ID, 0));
    }

    #[test]
    fn a_single_stream_of_any_id_is_taken() {
        let mut s = ResolverSelector::new(5 * MS, MS);
        for k in 0..5 {
            assert!(s.offer(0, k * 5 * MS, V));
        }
        assert_eq!(s.takeovers(), 0);
        // A standby that starts before the primary is taken until the primary commands.
        let mut s = ResolverSelector::new(5 * MS, MS);
        assert!(s.offer(STANDBY_RESOLVER_ID, 10 * MS, V));
        assert!(s.offer(PRIMARY_RESOLVER_ID, 11 * MS, V));
        assert!(!s.offer(STANDBY_RESOLVER_ID, 12 * MS, V));
        assert_eq!(s.takeovers(), 0);
    }
}
