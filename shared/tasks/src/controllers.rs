//! Commands of several controllers on one topic: during a hot swap the old and the new
//! final-phase controller publish side by side, and a consumer must use the active one's.
//! A plain latest value would hold whichever sample came last, so that the active
//! controller's command could be hidden behind the inactive one's for a cycle.
//! [`PerController`] keeps the newest command of each controller id instead.

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
}
