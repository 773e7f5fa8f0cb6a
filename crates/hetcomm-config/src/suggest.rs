//! "Did you mean …?" suggestions, for the fleet file's errors and for the tools that take
//! names from a user (the CLI's `--to`, `--as`, …). A dozen lines of edit distance are cheaper
//! than another dependency in the lock file every crate of the workspace shares.

/// Levenshtein distance, in characters.
pub fn distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    let mut cur = vec![0; b.len() + 1];
    for (i, ca) in a.chars().enumerate() {
        cur[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let subst = prev[j] + usize::from(ca != cb);
            cur[j + 1] = subst.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    prev[b.len()]
}

/// The candidate closest to `word`, if it is close enough to be a plausible typo.
pub fn closest<'a>(word: &str, candidates: &[&'a str]) -> Option<&'a str> {
    // A different case is always a plausible typo, however long the word.
    if let Some(c) = candidates.iter().find(|c| c.eq_ignore_ascii_case(word)) {
        return Some(c);
    }
    // One-character words (table letters) are all one edit apart, so suggesting any of them
    // would be noise.
    let limit = match word.chars().count() {
        0..=1 => 0,
        2..=3 => 1,
        4..=8 => 2,
        _ => 3,
    };
    candidates
        .iter()
        .map(|c| (distance(word, c), *c))
        .filter(|(d, _)| *d <= limit)
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

/// Help for an unknown word: the nearest candidate if there is one, else the whole list.
pub(crate) fn help(word: &str, candidates: &[&str], list_name: &str) -> String {
    match closest(word, candidates) {
        Some(c) => format!("did you mean `{c}`?"),
        None if candidates.is_empty() => format!("there are no {list_name}"),
        None => format!("{list_name}: {}", candidates.join(", ")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances() {
        assert_eq!(distance("endpoint", "endpoints"), 1);
        assert_eq!(distance("kitten", "sitting"), 3);
        assert_eq!(distance("", "abc"), 3);
    }

    #[test]
    fn suggestions() {
        let c = ["kind", "endpoints", "max_message_bytes"];
        assert_eq!(closest("endpoint", &c), Some("endpoints"));
        assert_eq!(closest("KIND", &c), Some("kind"));
        assert_eq!(closest("zzzzzz", &c), None);
        assert_eq!(
            help("endpont", &c, "valid keys"),
            "did you mean `endpoints`?"
        );
        assert_eq!(
            help("zzz", &c, "valid keys"),
            "valid keys: kind, endpoints, max_message_bytes"
        );
    }
}
