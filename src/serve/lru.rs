//! Lru: values kept by key within a byte budget, the least recently used evicted first.
//!
//! In: values with their size in bytes (an estimate the caller gives). Out: the value of a
//! key while it is kept. A value larger than the whole budget is never kept: its caller
//! uses it once and lets it go.

use std::collections::HashMap;

/// A cache of values by key, bounded by their total bytes.
pub struct Lru<V> {
    budget_bytes: u64,
    total_bytes: u64,
    /// Incremented at every use; a slot's `used` is the clock at its last use.
    clock: u64,
    slots: HashMap<String, Slot<V>>,
}

struct Slot<V> {
    value: V,
    bytes: u64,
    used: u64,
}

impl<V: Clone> Lru<V> {
    /// An empty cache holding at most `budget_bytes`.
    pub fn new(budget_bytes: u64) -> Lru<V> {
        Lru {
            budget_bytes,
            total_bytes: 0,
            clock: 0,
            slots: HashMap::new(),
        }
    }

    /// The value of `key`, marked as just used.
    pub fn get(&mut self, key: &str) -> Option<V> {
        self.clock += 1;
        let slot = self.slots.get_mut(key)?;
        slot.used = self.clock;
        Some(slot.value.clone())
    }

    /// Keeps `value` under `key`, evicting the least recently used values until it fits;
    /// a value larger than the budget is not kept.
    pub fn insert(&mut self, key: String, value: V, bytes: u64) {
        self.remove(&key);
        if bytes > self.budget_bytes {
            return;
        }
        while self.total_bytes + bytes > self.budget_bytes {
            let Some(oldest) = self
                .slots
                .iter()
                .min_by_key(|(_, s)| s.used)
                .map(|(k, _)| k.clone())
            else {
                break;
            };
            self.remove(&oldest);
        }
        self.clock += 1;
        self.total_bytes += bytes;
        let used = self.clock;
        self.slots.insert(key, Slot { value, bytes, used });
    }

    /// Drops the value of `key`, if kept.
    pub fn remove(&mut self, key: &str) {
        if let Some(slot) = self.slots.remove(key) {
            self.total_bytes -= slot.bytes;
        }
    }

    /// The bytes of the values kept.
    pub fn total_bytes(&self) -> u64 {
        self.total_bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_least_recently_used_value_goes_first() {
        let mut lru = Lru::new(30);
        lru.insert("a".into(), 1, 10);
        lru.insert("b".into(), 2, 10);
        lru.insert("c".into(), 3, 10);
        assert_eq!(lru.get("a"), Some(1)); // b is now the oldest
        lru.insert("d".into(), 4, 10);
        assert_eq!(lru.get("b"), None);
        assert_eq!(
            [lru.get("a"), lru.get("c"), lru.get("d")],
            [Some(1), Some(3), Some(4)]
        );
        assert_eq!(lru.total_bytes(), 30);
    }

    #[test]
    fn a_large_value_evicts_as_many_as_it_needs_and_no_more() {
        let mut lru = Lru::new(30);
        for (k, v) in ["a", "b", "c"].iter().zip(1..) {
            lru.insert(k.to_string(), v, 10);
        }
        lru.insert("big".into(), 9, 25);
        assert_eq!(lru.get("c"), None);
        assert_eq!(lru.get("big"), Some(9));
        assert_eq!(lru.total_bytes(), 25);
        lru.insert("huge".into(), 0, 31);
        assert_eq!(lru.get("huge"), None, "larger than the budget: not kept");
        assert_eq!(lru.get("big"), Some(9), "and nothing evicted for it");
    }

    #[test]
    fn replacing_a_key_counts_its_bytes_once() {
        let mut lru = Lru::new(100);
        lru.insert("a".into(), 1, 40);
        lru.insert("a".into(), 2, 50);
        assert_eq!(lru.total_bytes(), 50);
        lru.remove("a");
        assert_eq!(lru.total_bytes(), 0);
    }
}
