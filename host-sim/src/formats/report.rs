//! What a command prints: every command's result is a [`Report`], printed as JSON with
//! `--json` and as readable lines without. The lines are written beside the result's
//! type, so `main.rs` only chooses between the two.

use std::path::PathBuf;

use serde::Serialize;

/// A command's result as the user reads it.
pub trait Report: Serialize {
    /// The readable summary `dncal` prints without `--json`: whole lines, each ending in
    /// `\n`.
    fn text(&self) -> String;
}

/// Several inputs' reports (`dncal diagnose A B`): one after the other; a JSON array.
impl<T: Report> Report for [T] {
    fn text(&self) -> String {
        self.iter().map(Report::text).collect()
    }
}

/// One `wrote PATH` line per file written.
pub fn wrote(paths: &[PathBuf]) -> String {
    paths.iter().map(|p| format!("wrote {}\n", p.display())).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Line(&'static str);
    impl Report for Line {
        fn text(&self) -> String {
            format!("{}\n", self.0)
        }
    }

    #[test]
    fn several_reports_print_in_order_and_files_one_line_each() {
        assert_eq!([Line("a"), Line("b")][..].text(), "a\nb\n");
        assert_eq!(wrote(&[PathBuf::from("x/1.png"), PathBuf::from("2.fits")]), "wrote x/1.png\nwrote 2.fits\n");
        assert_eq!(wrote(&[]), "");
    }
}
