//! Which names a Rust source file imports, read from its text: shared by the test of the
//! crate's structure (`tests/structure.rs`: circles between modules and files) and the
//! test that a cache key hashes every file its build imports (`src/horizon/cache.rs`).
//!
//! In: a file's text and a path prefix (`super::`, `crate::horizon::`). Out: the first
//! names after each use of the prefix in its code, comments left out.

use std::collections::BTreeSet;

/// The names that follow `prefix` in `text`'s code (comments left out), each name of a
/// group `prefix{a, b::c}` too.
pub fn names_after(text: &str, prefix: &str) -> BTreeSet<String> {
    let name = |s: &str| -> String {
        s.trim()
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    let mut names = BTreeSet::new();
    for line in text.lines() {
        // `super::super::NAME` names a file of the folder above, not a sibling.
        let code = line
            .split("//")
            .next()
            .unwrap_or("")
            .replace("super::super::", "");
        for (at, _) in code.match_indices(prefix) {
            let rest = &code[at + prefix.len()..];
            match rest.strip_prefix('{') {
                Some(group) => names.extend(group.split(['}', ',']).map(name)),
                None => {
                    names.insert(name(rest));
                }
            }
        }
    }
    names.remove("");
    names
}
