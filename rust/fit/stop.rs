//! SPEC 5 step 5: when a frame's iteration stops (on the whole objective, elastic energy
//! included: see `fit_frame_with`).

/// Stops when the last decrease of $D$ is a small part of the total decrease so far,
/// unless penetrations are still being resolved (pushing nodes out of another part moves
/// them off their targets, so $D$ alone would stop those iterations early).
pub(super) struct StopRule {
    fraction: f64,
    first: Option<f64>,
    previous: Option<f64>,
    previous_contacts: usize,
}

impl StopRule {
    /// With the stopping `fraction` of the total decrease.
    pub(super) fn new(fraction: f64) -> Self {
        Self {
            fraction,
            first: None,
            previous: None,
            previous_contacts: 0,
        }
    }

    /// True to stop at an iterate with distance term `d` and `penetrating` surface nodes;
    /// otherwise the iterate is recorded and the iteration goes on.
    pub(super) fn should_stop(&mut self, d: f64, penetrating: usize) -> bool {
        if let (Some(d0), Some(last)) = (self.first, self.previous) {
            // Contacts present and not stalled (they appeared, or their count still falls).
            let stalled = self.previous_contacts > 0 && penetrating >= self.previous_contacts;
            let resolving = penetrating > 0 && !stalled;
            if !resolving && d0 - d > 0.0 && last - d < self.fraction * (d0 - d) {
                return true;
            }
        }
        self.first.get_or_insert(d);
        self.previous = Some(d);
        self.previous_contacts = penetrating;
        false
    }
}

#[cfg(test)]
mod tests {
    use super::StopRule;

    #[test]
    fn stops_on_a_small_last_decrease_unless_contacts_are_resolving() {
        let mut rule = StopRule::new(0.01);
        assert!(!rule.should_stop(10.0, 0));
        assert!(!rule.should_stop(5.0, 0));
        // Last decrease 0.01 of a total 5.01: stop.
        assert!(rule.should_stop(4.99, 0));
        let mut rule = StopRule::new(0.01);
        assert!(!rule.should_stop(10.0, 0));
        assert!(!rule.should_stop(5.0, 4));
        // Contacts falling (4 -> 2): still resolving, go on; stalled (2 -> 2): stop.
        assert!(!rule.should_stop(4.99, 2));
        assert!(rule.should_stop(4.989, 2));
    }
}
