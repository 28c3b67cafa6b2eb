//! The layout of a 2 x 2 Bayer colour filter, as the FITS convention of amateur and
//! industrial cameras names it (`BAYERPAT = 'RGGB'`, with `XBAYROFF`, `YBAYROFF` and
//! `ROWORDER`; written by MaxIm DL, SharpCap, ASCOM drivers, read by Siril and
//! PixInsight): the colours of the first two pixels of the first row, then of the second
//! row. Here the first row is the first row stored in the file unless `ROWORDER =
//! 'BOTTOM-UP'` says the file is stored from the bottom (then the layout starts at the
//! last row stored, as the image is shown).
//!
//! The layout is a label of the pixels, not their response: `dncal diagnose` measures
//! each cell's response (`cfa-pattern`) and says which colour each cell is where the file
//! declares the layout, and whether the cells that respond alike are the declared greens.

use serde::{Deserialize, Serialize};

/// One of the four 2 x 2 Bayer layouts: the colours of cells `(row 0, column 0)`, `(0,
/// 1)`, `(1, 0)`, `(1, 1)` of the sensor (or the set), in that order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Bayer {
    /// Red first, blue on the second row's second pixel.
    Rggb,
    /// Green, red; blue, green.
    Grbg,
    /// Green, blue; red, green.
    Gbrg,
    /// Blue first, red on the second row's second pixel.
    Bggr,
}

/// The colour of one cell of a Bayer filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Colour {
    Red,
    Green,
    Blue,
}

impl Colour {
    /// Its letter in a layout's name.
    pub fn letter(self) -> char {
        match self {
            Colour::Red => 'R',
            Colour::Green => 'G',
            Colour::Blue => 'B',
        }
    }

    /// Its name in prose.
    pub fn name(self) -> &'static str {
        match self {
            Colour::Red => "red",
            Colour::Green => "green",
            Colour::Blue => "blue",
        }
    }
}

/// A layout name that is none of the four.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not a Bayer layout: one of RGGB, GRBG, GBRG, BGGR")]
pub struct NotBayer(pub String);

impl Bayer {
    /// The four layouts.
    pub const ALL: [Bayer; 4] = [Bayer::Rggb, Bayer::Grbg, Bayer::Gbrg, Bayer::Bggr];

    /// Its name, as `BAYERPAT` holds it.
    pub fn name(self) -> &'static str {
        match self {
            Bayer::Rggb => "RGGB",
            Bayer::Grbg => "GRBG",
            Bayer::Gbrg => "GBRG",
            Bayer::Bggr => "BGGR",
        }
    }

    /// The layout of `name` (letters in either case, blanks around it ignored: FITS
    /// strings are blank-padded).
    pub fn parse(name: &str) -> Result<Bayer, NotBayer> {
        let n = name.trim().to_ascii_uppercase();
        Bayer::ALL.into_iter().find(|b| b.name() == n).ok_or_else(|| NotBayer(name.trim().to_string()))
    }

    /// The colour of cell `cell` (`(row mod 2) * 2 + column mod 2`, the order of the
    /// name's letters).
    pub fn colour(self, cell: usize) -> Colour {
        match self.name().as_bytes()[cell % 4] {
            b'R' => Colour::Red,
            b'G' => Colour::Green,
            _ => Colour::Blue,
        }
    }

    /// The colour of the pixel at `column`, `row`.
    pub fn colour_at(self, column: usize, row: usize) -> Colour {
        self.colour((row % 2) * 2 + column % 2)
    }

    /// The layout seen from `columns` columns and `rows` rows further on: that of a region
    /// whose first pixel is pixel (`columns`, `rows`) of this one (a region of interest, or
    /// `XBAYROFF` and `YBAYROFF`).
    pub fn shifted(self, columns: usize, rows: usize) -> Bayer {
        let name: String = (0..4).map(|k| self.colour_at(k % 2 + columns, k / 2 + rows).letter()).collect();
        // (A shifted Bayer layout is a Bayer layout: the greens stay on one diagonal.)
        Bayer::parse(&name).unwrap_or(self)
    }

    /// The two cells of the green diagonal: `[0, 3]` or `[1, 2]`.
    pub fn greens(self) -> [usize; 2] {
        match self {
            Bayer::Grbg | Bayer::Gbrg => [0, 3],
            Bayer::Rggb | Bayer::Bggr => [1, 2],
        }
    }
}

impl std::fmt::Display for Bayer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl TryFrom<String> for Bayer {
    type Error = NotBayer;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        Bayer::parse(&s)
    }
}

impl From<Bayer> for String {
    fn from(b: Bayer) -> String {
        b.name().to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Shifting by one column swaps the pixels of each row, by one row the rows; two of
    /// either is no shift (checked on the letters, written out by hand).
    #[test]
    fn a_layout_shifts_as_its_letters_do() {
        let by_hand = [
            // (layout, one column on, one row on, both)
            ("RGGB", "GRBG", "GBRG", "BGGR"),
            ("GRBG", "RGGB", "BGGR", "GBRG"),
            ("GBRG", "BGGR", "RGGB", "GRBG"),
            ("BGGR", "GBRG", "GRBG", "RGGB"),
        ];
        for (name, column, row, both) in by_hand {
            let b = Bayer::parse(name).unwrap();
            assert_eq!(b.name(), name);
            assert_eq!((b.shifted(1, 0).name(), b.shifted(0, 1).name(), b.shifted(1, 1).name()), (column, row, both));
            assert_eq!((b.shifted(2, 0), b.shifted(0, 4), b.shifted(3, 5)), (b, b, b.shifted(1, 1)));
        }
    }

    /// Colours by cell follow the name's letters; the greens are one diagonal.
    #[test]
    fn colours_and_greens_follow_the_name() {
        let b = Bayer::Gbrg;
        assert_eq!([b.colour(0), b.colour(1), b.colour(2), b.colour(3)], [Colour::Green, Colour::Blue, Colour::Red, Colour::Green]);
        assert_eq!(b.colour_at(4, 3), Colour::Red);
        for b in Bayer::ALL {
            let [g0, g1] = b.greens();
            assert!(b.colour(g0) == Colour::Green && b.colour(g1) == Colour::Green && g0 + g1 == 3, "{b}");
        }
    }

    /// FITS pads strings with blanks; case does not matter; anything else is refused.
    #[test]
    fn names_parse_padded_and_refuse_the_rest() {
        assert_eq!(Bayer::parse(" rggb   "), Ok(Bayer::Rggb));
        assert_eq!(Bayer::parse("RGBG"), Err(NotBayer("RGBG".into())));
        assert_eq!(Bayer::parse("").unwrap_err().to_string(), "\"\" is not a Bayer layout: one of RGGB, GRBG, GBRG, BGGR");
        let b: Bayer = serde_json::from_str("\"BGGR\"").unwrap();
        assert_eq!((b, serde_json::to_string(&b).unwrap()), (Bayer::Bggr, "\"BGGR\"".to_string()));
        assert!(serde_json::from_str::<Bayer>("\"XYZW\"").is_err());
    }
}
