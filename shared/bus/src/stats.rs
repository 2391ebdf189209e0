//! Cycle-time statistics of a service loop.

/// Nearest-rank percentile `p` (0–100) of `values`, reordering them; 0 when empty.
pub fn percentile(values: &mut [u64], p: f64) -> u64 {
    if values.is_empty() {
        return 0;
    }
    let rank = ((p / 100.0) * values.len() as f64).ceil() as usize;
    let index = rank.clamp(1, values.len()) - 1;
    *values.select_nth_unstable(index).1
}

/// Cycle counts, deadline misses and a window of recent cycle times for percentiles. Memory
/// is allocated once, at creation; recording never allocates.
#[derive(Debug, Clone)]
pub struct CycleStats {
    cycles: u64,
    deadline_misses: u64,
    max_cycle_ns: u64,
    last_deadline_miss_ns: u64,
    /// Ring buffer of the most recent cycle times, ns.
    window: Vec<u64>,
    /// Next ring-buffer slot to write.
    next: usize,
    /// Scratch space for percentile selection.
    scratch: Vec<u64>,
}

impl CycleStats {
    /// Statistics keeping the last `window` cycle times (at least one) for percentiles.
    pub fn new(window: usize) -> Self {
        let window = window.max(1);
        Self {
            cycles: 0,
            deadline_misses: 0,
            max_cycle_ns: 0,
            last_deadline_miss_ns: 0,
            window: Vec::with_capacity(window),
            next: 0,
            scratch: Vec::with_capacity(window),
        }
    }

    /// Records one cycle of `cycle_ns` that ended at `now_ns`; `missed` marks a deadline miss.
    pub fn record(&mut self, cycle_ns: u64, missed: bool, now_ns: u64) {
        self.cycles += 1;
        self.max_cycle_ns = self.max_cycle_ns.max(cycle_ns);
        if missed {
            self.deadline_misses += 1;
            self.last_deadline_miss_ns = now_ns;
        }
        if self.window.len() < self.window.capacity() {
            self.window.push(cycle_ns);
        } else {
            self.window[self.next] = cycle_ns;
        }
        self.next = (self.next + 1) % self.window.capacity();
    }

    /// Cycles recorded.
    pub fn cycles(&self) -> u64 {
        self.cycles
    }

    /// Cycles that missed their deadline.
    pub fn deadline_misses(&self) -> u64 {
        self.deadline_misses
    }

    /// Longest cycle recorded, ns.
    pub fn max_cycle_ns(&self) -> u64 {
        self.max_cycle_ns
    }

    /// Monotonic time of the last deadline miss, ns (0 when none).
    pub fn last_deadline_miss_ns(&self) -> u64 {
        self.last_deadline_miss_ns
    }

    /// Percentile `p` (0–100) of the recent cycle times, ns (0 before the first cycle).
    pub fn percentile_ns(&mut self, p: f64) -> u64 {
        self.scratch.clear();
        self.scratch.extend_from_slice(&self.window);
        percentile(&mut self.scratch, p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_uses_nearest_rank() {
        let mut v: Vec<u64> = (1..=100).rev().collect();
        assert_eq!(percentile(&mut v, 50.0), 50);
        assert_eq!(percentile(&mut v, 99.0), 99);
        assert_eq!(percentile(&mut v, 100.0), 100);
        assert_eq!(percentile(&mut v, 0.0), 1);
        assert_eq!(percentile(&mut [], 99.0), 0);
        assert_eq!(percentile(&mut [7], 99.0), 7);
    }

    #[test]
    fn stats_count_misses_and_keep_only_the_recent_window() {
        let mut s = CycleStats::new(4);
        for (i, ns) in [100, 900, 200, 300, 400, 500].into_iter().enumerate() {
            s.record(ns, ns == 900, 1000 + i as u64);
        }
        assert_eq!(s.cycles(), 6);
        assert_eq!(s.deadline_misses(), 1);
        assert_eq!(s.last_deadline_miss_ns(), 1001);
        assert_eq!(s.max_cycle_ns(), 900);
        // The window holds 200, 300, 400, 500: the 900 ns cycle has left it.
        assert_eq!(s.percentile_ns(100.0), 500);
        assert_eq!(s.percentile_ns(50.0), 300);
    }
}
