//! Each pixel's own fits on either half of its levels (a quartic and a straight line),
//! the bad-pixel flags they give, and the `bad-pixels` finding.

use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::finding;
use super::populations::populations;
use crate::analyses::diagnose::pixel_fit::{fit_and_score, Point, Response};
use crate::analyses::diagnose::points::{Common, Pixels};
use crate::analyses::diagnose::records::{Put, Record, Records, Take};
use crate::analyses::diagnose::{Effect, Finding, SIGNIFICANCE};
use crate::formats::fits::Sample;

/// A pixel's quartic on one half of its levels, what the catalogue reads of it: its
/// linear and quadratic coefficients, the `chi^2` of its fit, and the sum of its
/// held-out `z^2` on the other half with their count.
#[derive(Debug, Clone, Copy)]
pub(super) struct Quartic {
    pub(super) gain: f64,
    pub(super) b2: f64,
    pub(super) chi2_fit: f64,
    pub(super) held_sq: f64,
    pub(super) held_n: u16,
}

/// A pixel's fits on each half of its levels (even, odd): its quartic and its straight
/// line (dark DN, gain DN per reference unit), and the points each half had. Which fits
/// exist is a bit each (`fitted`) rather than four `Option`s: 120 bytes a pixel instead
/// of 152, held for every pixel through the diagnosis.
#[derive(Debug, Clone, Copy)]
pub(super) struct PixelFits {
    quartic: [Quartic; 2],
    line: [[f64; 2]; 2],
    pub(super) points: [u16; 2],
    /// Bit `h`: the quartic of half `h` exists; bit `2 + h`: its line.
    fitted: u8,
}

impl PixelFits {
    fn new(quartic: [Option<Quartic>; 2], line: [Option<[f64; 2]>; 2], points: [u16; 2]) -> Self {
        // A fit that does not exist holds what a lost record holds.
        let none = Self::LOST;
        let fitted = (0..2).map(|h| u8::from(quartic[h].is_some()) << h | u8::from(line[h].is_some()) << (2 + h)).sum();
        PixelFits { quartic: quartic.map(|q| q.unwrap_or(none.quartic[0])), line: line.map(|l| l.unwrap_or(none.line[0])), points, fitted }
    }

    /// The quartic of half `h` (0 even levels, 1 odd), where it was fitted.
    pub(super) fn quartic(&self, h: usize) -> Option<Quartic> {
        (self.fitted >> h & 1 == 1).then_some(self.quartic[h])
    }

    /// The straight line of half `h`, where it was fitted.
    pub(super) fn line(&self, h: usize) -> Option<[f64; 2]> {
        (self.fitted >> (2 + h) & 1 == 1).then_some(self.line[h])
    }
}

impl Record for PixelFits {
    const BYTES: usize = 2 * (4 * 8 + 2) + 4 * 8 + 2 * 2 + 1;
    const LOST: PixelFits = PixelFits {
        quartic: [Quartic { gain: f64::NAN, b2: f64::NAN, chi2_fit: f64::NAN, held_sq: f64::NAN, held_n: 0 }; 2],
        line: [[f64::NAN; 2]; 2],
        points: [0; 2],
        fitted: 0,
    };
    fn put(&self, out: &mut Put<'_>) {
        for q in &self.quartic {
            [q.gain, q.b2, q.chi2_fit, q.held_sq].into_iter().for_each(|v| out.f64(v));
            out.u16(q.held_n);
        }
        self.line.iter().flatten().for_each(|&v| out.f64(v));
        self.points.iter().for_each(|&p| out.u16(p));
        out.u8(self.fitted);
    }
    fn take(from: &mut Take<'_>) -> Self {
        let quartic = [(); 2].map(|_| Quartic { gain: from.f64(), b2: from.f64(), chi2_fit: from.f64(), held_sq: from.f64(), held_n: from.u16() });
        let line = [(); 2].map(|_| [from.f64(), from.f64()]);
        let points = [from.u16(), from.u16()];
        PixelFits { quartic, line, points, fitted: from.u8() }
    }
}

/// Why a pixel is flagged bad.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum BadPixel {
    /// Fewer than 3 unsaturated levels, or no fit: stuck, or hot at saturation.
    Stuck,
    /// Its own quartic fails its levels (kinks, jumps).
    Shape,
    /// A gain outside 0.5-1.5 of its ADC's median (dead).
    Gain,
    /// A dark level more than 10 robust sigma off (hot).
    Dark,
}

impl BadPixel {
    const ALL: [BadPixel; 4] = [BadPixel::Stuck, BadPixel::Shape, BadPixel::Gain, BadPixel::Dark];

    /// The kind's place in [`BadPixel::ALL`].
    fn place(self) -> usize {
        match self {
            BadPixel::Stuck => 0,
            BadPixel::Shape => 1,
            BadPixel::Gain => 2,
            BadPixel::Dark => 3,
        }
    }
}

/// A pixel's bad-pixel flags: on its even levels alone (for the held-out bad-pixel
/// score), and on both halves (the bad pixels: the kind found on the even levels).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Flags {
    even: Option<BadPixel>,
    both: Option<BadPixel>,
}

/// A byte each: 0 not flagged, else 1 + the kind's place in [`BadPixel::ALL`].
impl Record for Flags {
    const BYTES: usize = 2;
    const LOST: Flags = Flags { even: None, both: None };
    fn put(&self, out: &mut Put<'_>) {
        let code = |b: Option<BadPixel>| b.map_or(0, |b| 1 + b.place() as u8);
        out.u8(code(self.even));
        out.u8(code(self.both));
    }
    fn take(from: &mut Take<'_>) -> Self {
        let kind = |c: u8| usize::from(c).checked_sub(1).and_then(|k| BadPixel::ALL.get(k).copied());
        Flags { even: kind(from.u8()), both: kind(from.u8()) }
    }
}

/// The response every pixel's own quartic is (the paper's correction).
pub(super) const QUARTIC: Response = Response::Poly(crate::analyses::linearity::PIXEL_ORDER);
/// A straight line: dark and gain.
pub(super) const LINEAR: Response = Response::Poly(1);

/// Every pixel's fits on either half of its levels, the population of dark and gain
/// they give (per ADC and about each pixel's own ADC) and the bad-pixel flags.
pub(super) struct PixelStage {
    /// Per pixel (index into [`Pixels`]), held or spilled.
    pub(super) fits: Records<PixelFits>,
    /// The population the flags are set against.
    pop: Population,
    /// Per pixel, its flags on the even levels and on both halves.
    flags: Records<Flags>,
}

/// The population of dark and gain, from the even-level lines of even-row pixels.
struct Population {
    /// Dark (DN): the median of the ADCs' medians and the robust scatter about each
    /// pixel's own ADC median.
    dark_pop: (f64, f64),
    /// Gain (DN per reference unit), as `dark_pop`.
    gain_pop: (f64, f64),
    /// Per ADC, the median dark and gain.
    dark_adc: Vec<f64>,
    gain_adc: Vec<f64>,
}

impl Population {
    /// ADC `adc`'s median dark and gain, the population's where it has none.
    fn own(&self, adc: usize) -> (f64, f64) {
        let own = |v: &[f64], fallback: f64| v.get(adc).copied().filter(|x| x.is_finite()).unwrap_or(fallback);
        (own(&self.dark_adc, self.dark_pop.0), own(&self.gain_adc, self.gain_pop.0))
    }

    /// Why a pixel of fits `f` (of ADC `adc`, its colour channel's relative response
    /// `response`) is bad on one half of its levels (0 even, 1 odd).
    fn bad_in(&self, f: &PixelFits, adc: usize, response: f64, half: usize) -> Option<BadPixel> {
        let tail = |chi2: f64, dof: usize| dof > 0 && ChiSquared::new(dof as f64).map(|c| c.sf(chi2) < 1e-6).unwrap_or(false);
        let (Some(q), Some(l)) = (f.quartic(half), f.line(half)) else { return Some(BadPixel::Stuck) };
        let points = usize::from(f.points[half]);
        if points < 3 {
            return Some(BadPixel::Stuck);
        }
        if tail(q.chi2_fit, points.saturating_sub(QUARTIC.params())) {
            return Some(BadPixel::Shape);
        }
        let (dark_own, g_own) = self.own(adc);
        let gain = l[1] / response;
        if !(gain > 0.5 * g_own && gain < 1.5 * g_own) {
            return Some(BadPixel::Gain);
        }
        if (l[0] - dark_own).abs() > 10.0 * self.dark_pop.1.max(1e-9) {
            return Some(BadPixel::Dark);
        }
        None
    }
}

impl PixelStage {
    /// Fits every pixel of `px` (its means less `common`, where given) and flags the bad.
    pub(super) fn new<T: Sample>(px: &Pixels<T>, common: Option<&dyn Common>, n_adc: usize) -> Self {
        let n = px.len();
        // Each pixel's quartic on either half (the shapes for the shared curves, and the
        // bad-pixel test of the pixel's own response) and its straight line (dark and gain
        // for the maps: their parameters only).
        let zero5 = [0.0; 5];
        let fits = Records::from_fn(px.keep(), n, |i| {
            let (ev, od) = px.halves(i, common);
            let q = |a: &[Point], b: &[Point]| {
                fit_and_score(QUARTIC, &zero5, a, b).map(|s| Quartic { gain: s.params[1], b2: s.params[2], chi2_fit: s.chi2_fit, held_sq: s.sum_sq(), held_n: s.z.len() as u16 })
            };
            let l = |a: &[Point]| fit_and_score(LINEAR, &[0.0; 2], a, &[]).map(|s| [s.params[0], s.params[1]]);
            PixelFits::new([q(&ev, &od), q(&od, &ev)], [l(&ev), l(&od)], [ev.len() as u16, od.len() as u16])
        });
        // The population of dark (k = 0) and gain (k = 1) from the even-level fits, for the
        // bad-pixel flags.
        let [(dark_adc, dark_c, dark_s), (gain_adc, gain_c, gain_s)] = populations(n, n_adc, &|i, f| {
            if let Some(l) = fits.at(i).line(0).filter(|_| px.estimating(i)) {
                f(0, px.adc(i), l[0]);
                f(1, px.adc(i), l[1] / px.response(i));
            }
        });
        let pop = Population { dark_pop: (dark_c, dark_s), gain_pop: (gain_c, gain_s), dark_adc, gain_adc };
        // Each pixel is flagged against its own ADC's medians (an ADC offset is an
        // `adc-mismatch`, not a quarter of the sensor gone bad; a review found 1018 such
        // "bad pixels" with a 3 DN ADC offset and 0.2 DN of DSNU): on the even levels (for
        // the held-out bad-pixel score) and on both.
        let flags = Records::from_fn(px.keep(), n, |i| {
            let (f, adc, response) = (fits.at(i), px.adc(i), px.response(i));
            let even = pop.bad_in(&f, adc, response, 0);
            Flags { even, both: even.filter(|_| pop.bad_in(&f, adc, response, 1).is_some()) }
        });
        PixelStage { fits, pop, flags }
    }

    /// Not flagged, and fitted on the even levels.
    pub(super) fn is_good(&self, i: usize) -> bool {
        self.flags.at(i).both.is_none() && { let f = self.fits.at(i); f.quartic(0).is_some() && f.line(0).is_some() }
    }

    /// Pixels flagged bad, of each kind (in [`BadPixel::ALL`]'s order).
    fn bad_counts(&self) -> [usize; 4] {
        let mut n = [0; 4];
        for b in self.flags.iter().filter_map(|f| f.both) {
            n[b.place()] += 1;
        }
        n
    }

    /// Pixels flagged bad.
    pub(super) fn bad_count(&self) -> usize {
        self.bad_counts().iter().sum()
    }

    /// `bad-pixels`: the flagged pixels scored on the odd levels' dark and gain against the
    /// population, plus the held-out level residuals of the pixel's own quartic.
    pub(super) fn finding<T: Sample>(&self, px: &Pixels<T>) -> Option<Finding> {
        let (fits, (dark_pop, gain_pop)) = (&self.fits, (self.pop.dark_pop, self.pop.gain_pop));
        let kinds = self.bad_counts();
        let flagged: usize = kinds.iter().sum();
        if flagged == 0 {
            return None;
        }
        // A pixel's sum of squares and count of scores.
        let map_z = |i: usize| -> (f64, usize) {
            let (dark_own, gain_own) = self.pop.own(px.adc(i));
            let f = fits.at(i);
            match (&f.line(1), &f.quartic(0)) {
                (Some(l), Some(q)) => {
                    let z = [(l[0] - dark_own) / dark_pop.1.max(1e-9), (l[1] / px.response(i) - gain_own) / gain_pop.1.max(1e-9)];
                    (z[0] * z[0] + z[1] * z[1] + q.held_sq, 2 + usize::from(q.held_n))
                }
                // Stuck: its raw dark level against the population.
                _ => (((px.mean(0, i) - dark_own) / dark_pop.1.max(1e-9)).powi(2), 1),
            }
        };
        // Scored held out: the pixels set apart are those flagged on the even levels alone,
        // and every score is of the odd levels (the odd-level fit's dark and gain, the
        // even-level quartic's residuals there); the count needs both halves.
        let (mut s_all, mut n_all, mut s_ok, mut n_ok) = (0.0, 0usize, 0.0, 0usize);
        for (i, flags) in self.flags.iter().enumerate() {
            let (s, len) = map_z(i);
            s_all += s;
            n_all += len;
            if flags.even.is_none() {
                s_ok += s;
                n_ok += len;
            }
        }
        let (before, after) = ((s_all / n_all.max(1) as f64).sqrt(), (s_ok / n_ok.max(1) as f64).sqrt());
        // The significance is that of the set-apart pixels' odd-level excess over what
        // noise leaves in them (one per residual).
        let removed = (n_all - n_ok) as f64;
        let significance = (s_all - s_ok - removed) / (2.0 * n_all as f64).sqrt();
        (significance > SIGNIFICANCE).then(|| {
            let mut f = finding(
                Effect::BadPixels,
                None,
                significance,
                before,
                after,
                format!(
                    "{} pixels the model cannot follow, flagged independently on even and odd levels: {} stuck or hot at saturation, {} whose own quartic fails its levels, {} with a gain outside 0.5-1.5 of the median, {} with a dark level beyond 10 robust sigma",
                    flagged, kinds[0], kinds[1], kinds[2], kinds[3]
                ),
            );
            f.count = Some(flagged);
            f
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the diagnosis holds per pixel for its fits and per pixel and model for its
    /// scores (the budget's `RECORD_BYTES` counts them held), and the fits read back as
    /// they were given.
    #[test]
    fn the_per_pixel_records_are_their_stated_size_and_read_back() {
        assert_eq!(std::mem::size_of::<PixelFits>(), 120);
        assert_eq!(std::mem::size_of::<super::super::super::scores::Score>(), 24);
        // The budget's records held: these fits, the level term's (a quartic, a quadratic
        // and a line, each an `Option`, and the frame variance's fit), five models' scores
        // and a pair of values; the unsaturated levels, the pixel's and the good pixel's
        // indices and the flags.
        let level = super::super::super::levels::LEVEL_FIT_BYTES;
        assert_eq!(level, 200);
        assert_eq!(std::mem::size_of::<Flags>(), 2);
        let small = std::mem::size_of::<u16>() + 2 * std::mem::size_of::<u32>() + std::mem::size_of::<Flags>();
        assert_eq!(super::super::super::records::RECORD_BYTES as usize, 120 + level + 5 * 24 + std::mem::size_of::<[f64; 2]>() + small);
        let q = Quartic { gain: 2.0, b2: -0.5, chi2_fit: 3.0, held_sq: 4.0, held_n: 7 };
        let f = PixelFits::new([None, Some(q)], [Some([1.0, 2.0]), None], [5, 6]);
        assert!(f.quartic(0).is_none() && f.line(1).is_none());
        assert_eq!((f.quartic(1).map(|q| (q.gain, q.b2, q.chi2_fit, q.held_sq, q.held_n)), f.line(0)), (Some((2.0, -0.5, 3.0, 4.0, 7)), Some([1.0, 2.0])));
        // Every flag reads back as written.
        let kinds = [None, Some(BadPixel::Stuck), Some(BadPixel::Shape), Some(BadPixel::Gain), Some(BadPixel::Dark)];
        for even in kinds {
            for both in kinds {
                let f = Flags { even, both };
                assert_eq!(super::super::super::records::round_trip(f), f);
            }
        }
        // A fitted line of NaN is still a fitted line (the marker is the bit, not a value).
        assert_eq!(PixelFits::new([None, None], [None, Some([f64::NAN; 2])], [0, 0]).line(1).map(|l| l[0].is_nan()), Some(true));
        // Spilled and read back, every field and fit bit as it was (a negative zero too).
        let g = PixelFits::new([Some(Quartic { held_n: 65_535, ..q }), None], [Some([-0.0, f64::MIN_POSITIVE]), Some([1e300, -3.5])], [7, 65_535]);
        let bits = |f: PixelFits| {
            let q = f.quartic.map(|q| [q.gain, q.b2, q.chi2_fit, q.held_sq].map(f64::to_bits));
            (q, f.quartic.map(|q| q.held_n), f.line.map(|l| l.map(f64::to_bits)), f.points, f.fitted)
        };
        for f in [f, g, PixelFits::LOST] {
            assert_eq!(bits(super::super::super::records::round_trip(f)), bits(f));
        }
    }
}
