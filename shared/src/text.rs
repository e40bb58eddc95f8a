//! Text from a bundle made safe for a terminal or a log: a bundle's names are free text from
//! whoever signed it (or, under `inspect`, from anyone), and a control character in them
//! could move the cursor, erase a line or reorder what is shown.

use std::borrow::Cow;

/// Whether `c` must not reach a terminal: C0 controls (ESC, CR, LF, BEL, TAB, ...), DEL, C1
/// controls (U+0080..=U+009F: CSI is U+009B), and the bidirectional formatting characters
/// (embeddings and overrides U+202A..=U+202E, isolates U+2066..=U+2069, and the marks U+200E,
/// U+200F, U+061C), which reorder the text around them.
pub fn is_unsafe(c: char) -> bool {
    matches!(
        c,
        '\u{0}'..='\u{1f}'
            | '\u{7f}'..='\u{9f}'
            | '\u{202a}'..='\u{202e}'
            | '\u{2066}'..='\u{2069}'
            | '\u{200e}'
            | '\u{200f}'
            | '\u{61c}'
    )
}

/// `s` with every [`is_unsafe`] character escaped as Rust's `escape_debug` writes it (`\n`,
/// `\r`, `\t`, `\0`, `\u{1b}`, `\u{202e}`); everything else, ordinary non-ASCII letters
/// included, is kept as it is. Borrowed (no copy) when there is nothing to escape. Use it for
/// every bundle-supplied string printed or logged; HTML and JSON have their own escaping.
pub fn printable(s: &str) -> Cow<'_, str> {
    if !s.chars().any(is_unsafe) {
        return Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 8);
    for c in s.chars() {
        if is_unsafe(c) {
            out.extend(c.escape_debug());
        } else {
            out.push(c);
        }
    }
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    #[test]
    fn escapes_controls_and_keeps_letters() {
        assert!(matches!(printable("Casas Grandes effigy jar"), Cow::Borrowed(_)));
        assert_eq!(printable("Vénus, 維納斯, Венера"), "Vénus, 維納斯, Венера");
        assert_eq!(printable("a\"b'c\\d"), "a\"b'c\\d");
        assert_eq!(printable("\u{1b}[2K\rsignature: verified"), "\\u{1b}[2K\\rsignature: verified");
        assert_eq!(printable("a\u{7}b\u{7f}c\u{9b}d\te\n\0"), "a\\u{7}b\\u{7f}c\\u{9b}d\\te\\n\\0");
        assert_eq!(printable("x\u{202e}gpj.exe\u{2066}\u{2069}"), "x\\u{202e}gpj.exe\\u{2066}\\u{2069}");
        assert_eq!(printable("\u{200e}\u{200f}\u{61c}"), "\\u{200e}\\u{200f}\\u{61c}");
    }

    /// Text with unsafe characters mixed in (`any::<String>()` avoids control characters).
    fn text() -> impl Strategy<Value = String> {
        let unsafe_chars = prop::sample::select(vec![
            '\0', '\t', '\n', '\r', '\u{7}', '\u{1b}', '\u{7f}', '\u{85}', '\u{9b}', '\u{61c}', '\u{200e}',
            '\u{202a}', '\u{202e}', '\u{2066}', '\u{2069}',
        ]);
        prop::collection::vec(prop_oneof![any::<char>(), unsafe_chars], 0..40)
            .prop_map(|v| v.into_iter().collect())
    }

    proptest! {
        #[test]
        fn nothing_unsafe_survives(s in text()) {
            let p = printable(&s);
            prop_assert!(!p.chars().any(is_unsafe), "{:?}", p);
            if !s.chars().any(is_unsafe) {
                prop_assert!(matches!(p, Cow::Borrowed(b) if b == s));
            }
        }
    }
}
