//! Names of systems, modules and transports: one spelling per name, and the characters a
//! system or module name may use.
//!
//! Unicode can spell `é` as one code point (U+00E9) or as `e` followed by a combining accent
//! (U+0065 U+0301); editors and keyboards produce either. Every name, and every reference to
//! one, is put in Normalization Form C before it is compared, so the two spellings are one
//! name (and two systems spelled only differently are reported as a duplicate).

use std::borrow::Cow;

use unicode_normalization::{is_nfc_quick, IsNormalized, UnicodeNormalization};

/// The characters a system or module name may contain, as error messages and docs say it.
pub(crate) const NAME_CHARS: &str =
    "letters, digits, combining marks, `_`, `-`, `.`, and spaces between words";

/// `s` in Unicode Normalization Form C (borrowed when it already is, as ASCII always is).
pub(crate) fn nfc(s: &str) -> Cow<'_, str> {
    if s.is_ascii() || is_nfc_quick(s.chars()) == IsNormalized::Yes {
        Cow::Borrowed(s)
    } else {
        let n: String = s.nfc().collect();
        if n == s {
            Cow::Borrowed(s)
        } else {
            Cow::Owned(n)
        }
    }
}

/// The first character of `name` that a system or module name may not contain, if any (see
/// [`NAME_CHARS`]); a space at either end counts as one.
pub(crate) fn bad_char(name: &str) -> Option<char> {
    let allowed = |c: char| {
        c.is_alphanumeric()
            || unicode_normalization::char::is_combining_mark(c)
            || matches!(c, '_' | '-' | '.' | ' ')
    };
    if let Some(c) = name.chars().find(|&c| !allowed(c)) {
        return Some(c);
    }
    [name.chars().next(), name.chars().last()]
        .into_iter()
        .flatten()
        .find(|&c| c == ' ')
}

/// A character for a message: its code point, after the character itself in backquotes when
/// it is surely visible (invisible ones, such as U+200B, would only confuse).
pub(crate) fn describe(c: char) -> String {
    if (c.is_ascii_graphic() && c != '`') || (!c.is_ascii() && c.is_alphanumeric()) {
        format!("`{c}` (U+{:04X})", u32::from(c))
    } else {
        format!("U+{:04X}", u32::from(c))
    }
}

/// `name` for a message, with characters that may not show (controls, invisible and other
/// non-graphic characters, spaces other than U+0020) written as `\u{XXXX}`.
pub(crate) fn visible(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c == ' '
                || c.is_ascii_graphic()
                || (!c.is_ascii()
                    && (c.is_alphanumeric() || unicode_normalization::char::is_combining_mark(c)))
            {
                c.to_string()
            } else {
                format!("\\u{{{:04X}}}", u32::from(c))
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_spellings_of_one_name_normalise_alike() {
        let composed = "Caf\u{e9}";
        let decomposed = "Cafe\u{301}";
        assert_ne!(composed, decomposed);
        assert_eq!(nfc(composed), nfc(decomposed));
        assert!(matches!(nfc("Alpha"), Cow::Borrowed(_)));
    }

    #[test]
    fn allowed_characters() {
        for ok in [
            "Alpha",
            "Virtual Environment",
            "robot_1",
            "r-2.b",
            "Caf\u{e9}",
            "Cafe\u{301}",
            "ロボット",
        ] {
            assert_eq!(bad_char(ok), None, "{ok:?}");
        }
        assert_eq!(bad_char("a#b"), Some('#'));
        assert_eq!(bad_char("zero\u{200b}width"), Some('\u{200b}'));
        assert_eq!(bad_char("tab\there"), Some('\t'));
        assert_eq!(bad_char(" lead"), Some(' '));
        assert_eq!(bad_char("trail "), Some(' '));
        assert_eq!(describe('\u{200b}'), "U+200B");
        assert_eq!(describe('#'), "`#` (U+0023)");
        assert_eq!(visible("a\u{200b}b\tc d#"), "a\\u{200B}b\\u{0009}c d#");
    }
}
