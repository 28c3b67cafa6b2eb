//! Text from files made safe to print on a terminal (issue 43).

/// `text` as a terminal may show it: every control character (C0 and DEL, C1, which
/// include ESC, BEL and form feed, and line breaks: a message is one line) and every
/// bidirectional override (which can make text read in another order than it is)
/// written as its escape, `\x1b` or `\u{202e}`. Messages quote bytes
/// from files (a header's `ADCMAP`, a path); printed raw, an `ESC ] 0 ;` in one set the
/// terminal's title (issue 43).
pub fn printable(text: &str) -> std::borrow::Cow<'_, str> {
    let escaped = |c: char| c.is_control() || matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}');
    if !text.chars().any(escaped) {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 8);
    for c in text.chars() {
        match c {
            c if escaped(c) && (c as u32) < 0x80 => out.push_str(&format!("\\x{:02x}", c as u32)),
            c if escaped(c) => out.push_str(&format!("\\u{{{:x}}}", c as u32)),
            c => out.push(c),
        }
    }
    std::borrow::Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_characters_are_printed_as_escapes() {
        assert_eq!(printable("plain: é ü 1e-3"), "plain: é ü 1e-3");
        assert_eq!(printable("ADCMAP = '\u{1b}]0;pwned\u{7}'"), "ADCMAP = '\\x1b]0;pwned\\x07'");
        assert_eq!(printable("a\u{c}b\nc\rd\te\u{7f}"), "a\\x0cb\\x0ac\\x0dd\\x09e\\x7f");
        assert_eq!(printable("\u{85}x\u{202e}y"), "\\u{85}x\\u{202e}y");
    }
}
