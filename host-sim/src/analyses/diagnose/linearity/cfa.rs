//! `cfa-pattern`: a response that repeats with a small period in rows and columns
//! together, as a colour filter array makes it (issue 58). Found before any other test,
//! because every later step compares a pixel's gain with a population: a Bayer filter's
//! red channel at 0.55 of the mean read as a quarter of the sensor dead (200-500 sigma
//! `bad-pixels` on a consumer camera), and column ADCs that each read one colour more
//! than another as an `adc-mismatch`. Found, the pattern divides every pixel's gain
//! before it meets a population (each channel against its own: PRNU within a channel,
//! defects against the channel's pixels).
//!
//! ## The test
//! Each pixel's signal `s = m_L - m_0` at a level `L` below saturation for most pixels
//! (70% of the median pixel's unsaturated levels; a difference of two levels, so a level
//! 0 that is not dark does not matter). For each period `P` of [`PERIODS`], the pixels
//! fall into `P x P` classes by `(row mod P, column mod P)`; a class's response is its
//! median signal over the mean of the classes' medians, with standard error
//! `1.2533 sd / sqrt(n)` (`sd`: 1.4826 MAD within the class). Only the **interaction**
//! of rows and columns of the responses' logarithms is tested (the classes less their
//! row means and column means; logarithms because gains multiply, and a column effect
//! times a row effect has no interaction there):
//! a pattern of columns alone is what column ADCs (`adc-mismatch`) or column amplifiers
//! make, one of rows alone what a two-sided readout makes, and neither is a colour
//! filter. A Bayer filter's interaction is `(2G - R - B) / 4`, 0.23 of the mean on the
//! consumer camera of issue 58.
//!
//! **Held out by pixels**: the rows fall into two halves by `(row / P) mod 2` (each half
//! holds every class); the pattern found on one half is the template the other is
//! projected on, `z = sum I_A I_B / (se_B sqrt(sum I_A^2))`, which is N(0, 1) when the
//! held-out half has no pattern and the classes' errors are independent (pixels whose
//! neighbours' gains correlate widen it; for P = 3 the halves hold opposite rows of a
//! period-2 structure, which makes z negative, never a false acceptance). Accepted when
//! both ways round give `z > 5`. A larger period that is a multiple (4 of 2, 6 of 2 and
//! 3) is taken only where it passes alone and the interaction of what it adds to the
//! smaller one's pattern passes the same test.
//!
//! ## What it cannot tell apart
//! With column ADCs the pattern's column part and a gain difference between the ADCs of
//! even and odd columns are the same data: the channels' responses carry the mean gain
//! of each column parity's ADCs, so one ADC's gain error on a 2 x 2 filter with four
//! column ADCs shows in `adc-mismatch` as its own and half of it, of the opposite sign,
//! on the other ADC of its parity (not yet compared within a parity: issue 58).

use super::*;
use crate::analyses::diagnose::channels::CfaResponse;
use crate::formats::bayer::Bayer;
use crate::infra::select::robust;

/// The periods tested, rows and columns alike: Bayer (2), the 3 x 3 halves of an X-Trans
/// filter (3, 6), quad-Bayer (4).
pub(super) const PERIODS: [usize; 4] = [2, 3, 4, 6];

/// Per class of one period and one set of pixels: median, robust spread (signal units)
/// and count.
#[derive(Debug, Clone)]
struct Classes {
    median: Vec<f64>,
    sd: Vec<f64>,
    n: Vec<usize>,
}

impl Classes {
    /// The classes' mean median: the unit of the responses.
    fn unit(&self) -> f64 {
        crate::infra::stats::mean(&self.median)
    }

    /// Responses relative to the classes' mean.
    fn response(&self) -> Vec<f64> {
        let u = self.unit();
        self.median.iter().map(|m| m / u).collect()
    }

    /// The responses' logarithms: gains multiply, so a column effect (an ADC's gain)
    /// times a row effect (a two-sided readout) has no interaction in the logarithm, where
    /// on the ratios it has `a_c b_r` (a review measured a false pattern at z = 7 on a
    /// 512 x 512 monochrome sensor with ADCs 3% and rows 4% apart).
    fn log_response(&self) -> Vec<f64> {
        self.response().iter().map(|r| r.ln()).collect()
    }

    /// The pooled standard error of one class's log response (`1.2533 sd / (median
    /// sqrt(n))`, its variance averaged over the classes).
    fn pooled_se(&self) -> f64 {
        let v: Vec<f64> = self
            .sd
            .iter()
            .zip(&self.n)
            .zip(&self.median)
            .map(|((s, &n), m)| (1.2533 * s / m).powi(2) / n.max(1) as f64)
            .collect();
        crate::infra::stats::mean(&v).sqrt()
    }
}

/// The interaction of rows and columns of a `p x p` table: `t - row mean - column mean +
/// mean`.
fn interaction(t: &[f64], p: usize) -> Vec<f64> {
    let row = |r: usize| (0..p).map(|c| t[r * p + c]).sum::<f64>() / p as f64;
    let col = |c: usize| (0..p).map(|r| t[r * p + c]).sum::<f64>() / p as f64;
    let all = t.iter().sum::<f64>() / (p * p) as f64;
    (0..p * p)
        .map(|k| t[k] - row(k / p) - col(k % p) + all)
        .collect()
}

/// `t` of period `small` repeated over a `big x big` table.
fn alias(t: &[f64], small: usize, big: usize) -> Vec<f64> {
    (0..big * big)
        .map(|k| t[((k / big) % small) * small + (k % big) % small])
        .collect()
}

/// The held-out projection `z` of `b`'s table on the template `a` (module documentation),
/// `se_b` the standard error of one of `b`'s entries. Zero for a template without
/// structure.
fn projection(a: &[f64], b: &[f64], se_b: f64) -> f64 {
    let norm = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm <= 0.0 || se_b <= 0.0 || !norm.is_finite() {
        return 0.0;
    }
    a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>() / (se_b * norm)
}

/// Both ways round: the smaller `z`.
fn held_out(a: &[f64], b: &[f64], se_a: f64, se_b: f64) -> f64 {
    projection(a, b, se_b).min(projection(b, a, se_a))
}

/// The outcome of [`cfa_stage`].
pub(super) struct CfaStage {
    /// The pattern, where one was found.
    pub response: Option<CfaResponse>,
    /// Its finding.
    pub finding: Option<Finding>,
    /// Where the file declares a Bayer layout and no pattern was found: what that means.
    pub note: Option<String>,
}

/// The class statistics of every period of [`PERIODS`] for the halves (0, 1) and all
/// pixels (2): index `[period][set]`. `signal(i)` is pixel `i`'s signal (NaN: left out).
fn classes<T: Sample>(px: &Pixels<T>, signal: &(dyn Fn(usize) -> f64 + Sync)) -> Vec<[Classes; 3]> {
    let offsets: Vec<usize> = PERIODS
        .iter()
        .scan(0, |o, &p| {
            let at = *o;
            *o += 3 * p * p;
            Some(at)
        })
        .collect();
    let cells = offsets.last().copied().unwrap_or(0) + 3 * PERIODS[PERIODS.len() - 1].pow(2);
    let cell_of = |i: usize, k: usize, set: usize| {
        let (c, r) = px.position(i);
        let p = PERIODS[k];
        offsets[k] + set * p * p + crate::model::camera::config::cfa_cell(c, r, p)
    };
    let half_of = |i: usize, k: usize| (px.position(i).1 / PERIODS[k]) % 2;
    let stats = robust(px.len(), cells, &|i, f| {
        let s = signal(i);
        for k in 0..PERIODS.len() {
            f(cell_of(i, k, half_of(i, k)), s);
            f(cell_of(i, k, 2), s);
        }
    });
    let mut counts = vec![0usize; cells];
    for i in 0..px.len() {
        if signal(i).is_finite() {
            for k in 0..PERIODS.len() {
                counts[cell_of(i, k, half_of(i, k))] += 1;
                counts[cell_of(i, k, 2)] += 1;
            }
        }
    }
    PERIODS
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            std::array::from_fn(|set| {
                let range = offsets[k] + set * p * p..offsets[k] + (set + 1) * p * p;
                Classes {
                    median: stats[range.clone()].iter().map(|s| s.0).collect(),
                    sd: stats[range.clone()].iter().map(|s| s.1).collect(),
                    n: counts[range].to_vec(),
                }
            })
        })
        .collect()
}

/// The level whose signal the test reads: 70% of the median pixel's unsaturated levels
/// (at least 1); `None` where the median pixel has fewer than two.
fn signal_level<T: Sample>(px: &Pixels<T>) -> Option<usize> {
    let valid =
        crate::infra::select::upper_medians(px.len(), 1, &|i, f| f(0, px.valid(i) as f64))[0];
    (valid >= 2.0).then(|| ((0.7 * (valid - 1.0)) as usize).max(1))
}

/// Finds a colour filter's response pattern in `px` (module documentation); `declared`
/// is the file's Bayer layout (`BAYERPAT`), which names the cells' colours and is checked
/// against the cells that respond alike, never used to find the pattern.
pub(super) fn cfa_stage<T: Sample>(px: &Pixels<T>, declared: Option<Bayer>) -> CfaStage {
    let none = |why: &str| CfaStage {
        response: None,
        finding: None,
        note: declared.map(|b| format!("cfa-pattern: the file declares a {b} colour filter (BAYERPAT), but {why}: every pixel meets the whole sensor's population, not its colour's")),
    };
    let Some(level) = signal_level(px) else {
        return none("the median pixel has fewer than two levels below saturation to read the channels' responses on");
    };
    let signal = |i: usize| {
        if level < px.valid(i) {
            px.with_levels(i, |at| at.mean(level) - at.mean(0))
        } else {
            f64::NAN
        }
    };
    let (width, height) = px.size();
    let all = classes(px, &signal);
    // Per period: its held-out z (NaN where the sensor holds fewer than two periods of
    // rows a half, or a class is empty).
    let z_of = |k: usize| -> f64 {
        let [a, b, _] = &all[k];
        let p = PERIODS[k];
        if width < 2 * p || height < 4 * p || a.n.iter().chain(&b.n).any(|&n| n < 2) {
            return f64::NAN;
        }
        held_out(
            &interaction(&a.log_response(), p),
            &interaction(&b.log_response(), p),
            a.pooled_se(),
            b.pooled_se(),
        )
    };
    let z: Vec<f64> = (0..PERIODS.len()).map(z_of).collect();
    let Some(mut k) = (0..PERIODS.len()).find(|&k| z[k] > SIGNIFICANCE) else {
        let why = match z[0] {
            z if z.is_finite() => format!("its channels respond alike (a 2 x 2 pattern held out by rows at z = {z:.1}, below {SIGNIFICANCE}; white light through filters of equal response, or a monochrome sensor)"),
            _ => "the set is too small to hold out a 2 x 2 pattern (two periods of rows a half)".into(),
        };
        return none(&why);
    };
    let mut significance = z[k];
    // A multiple of the period where what it adds stands out, held out alike: the
    // interaction of the larger table less the smaller one's (interaction and aliasing
    // commute), so that a pattern of columns alone (4 column ADCs' gains) is not taken
    // for a 4 x 4 filter (a review found it so on every seed of a Bayer set with one ADC
    // 3% off).
    for m in k + 1..PERIODS.len() {
        let (p, big) = (PERIODS[k], PERIODS[m]);
        if big % p != 0 || z[m].is_nan() || z[m] <= SIGNIFICANCE {
            continue;
        }
        let [a, b, _] = &all[m];
        let [sa, sb, _] = &all[k];
        let extra = |c: &Classes, s: &Classes| -> Vec<f64> {
            let added: Vec<f64> = c
                .log_response()
                .iter()
                .zip(alias(&s.log_response(), p, big))
                .map(|(x, y)| x - y)
                .collect();
            interaction(&added, big)
        };
        let added = held_out(&extra(a, sa), &extra(b, sb), a.pooled_se(), b.pooled_se());
        if added > SIGNIFICANCE {
            (k, significance) = (m, z[m]);
        }
    }
    let [a, b, whole] = &all[k];
    let p = PERIODS[k];
    let response = whole.response();
    let prnu_within: Vec<f64> = whole
        .sd
        .iter()
        .zip(&whole.median)
        .map(|(s, m)| s / m)
        .collect();
    // The held-out spread of the responses in units of the pixels' own scatter: half B
    // about one population, then about half A's classes.
    let pooled_sd = {
        let u = b.unit();
        crate::infra::stats::mean(&b.sd.iter().map(|s| (s / u).powi(2)).collect::<Vec<_>>()).sqrt()
    };
    let (ra, rb) = (a.response(), b.response());
    let before = (1.0
        + crate::infra::stats::mean(&rb.iter().map(|x| (x - 1.0).powi(2)).collect::<Vec<_>>())
            / pooled_sd.powi(2))
    .sqrt();
    let after = (1.0
        + crate::infra::stats::mean(
            &rb.iter()
                .zip(&ra)
                .map(|(x, y)| (x - y).powi(2))
                .collect::<Vec<_>>(),
        ) / pooled_sd.powi(2))
    .sqrt();
    let cells: Vec<String> = response
        .iter()
        .enumerate()
        .map(|(c, r)| format!("({}, {}) {r:.3}", c / p, c % p))
        .collect();
    let within: Vec<f64> = prnu_within.iter().map(|v| 100.0 * v).collect();
    let overall = {
        let u = whole.unit();
        100.0
            * crate::infra::stats::mean(
                &whole
                    .sd
                    .iter()
                    .zip(&response)
                    .map(|(s, r)| (s / u).powi(2) + (r - 1.0).powi(2))
                    .collect::<Vec<_>>(),
            )
            .sqrt()
    };
    let bayer = match (p, declared) {
        (2, Some(b)) => declared_text(b, &response, whole.pooled_se()),
        (_, Some(b)) => format!("; the file declares a 2 x 2 {b} layout (BAYERPAT), but the pattern's period is {p}"),
        _ => (p == 2).then(|| bayer_text(&response, &whole.pooled_se())).flatten().unwrap_or_default(),
    };
    let finding = finding(
        Effect::CfaPattern,
        None,
        significance,
        before,
        after,
        format!(
            "a {p} x {p} pattern of response in rows and columns together (a colour filter array), held out by rows: cells (row, column mod {p}) {} of their mean{bayer}; PRNU within a channel {:.2}-{:.2}% against {overall:.1}% over all pixels (level {level}, its means' noise included). Each pixel's gain meets its own channel's population from here (defects, PRNU, ADC offsets and gains)",
            cells.join(", "),
            within.iter().cloned().fold(f64::INFINITY, f64::min),
            within.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        ),
    );
    let carried = declared.filter(|b| p == 2 && greens_alike(*b, &response, whole.pooled_se()));
    CfaStage {
        response: Some(CfaResponse {
            period: p,
            response,
            prnu_within,
            // (Carried into the model only where its greens are the cells alike: a layout
            // the pixels say is off would be written out again as BAYERPAT.)
            bayer: carried,
        }),
        finding: Some(finding),
        note: None,
    }
}

/// Whether two responses are alike: within 5 standard errors of their difference
/// (`se` one response's) and 2% of the first.
fn alike(a: f64, b: f64, se: f64) -> bool {
    (a - b).abs() <= (5.0 * se * std::f64::consts::SQRT_2).max(0.02 * a.abs())
}

/// Of the declared layout's two diagonals: whether its greens respond alike, whether the
/// other diagonal's cells do, and those cells.
fn diagonals(b: Bayer, r: &[f64], se: f64) -> (bool, bool, [usize; 2]) {
    let [g0, g1] = b.greens();
    let other = if g0 == 0 { [1, 2] } else { [0, 3] };
    (alike(r[g0], r[g1], se), alike(r[other[0]], r[other[1]], se), other)
}

/// Whether the declared layout's greens respond alike and its other diagonal does not.
fn greens_alike(b: Bayer, r: &[f64], se: f64) -> bool {
    matches!(diagonals(b, r, se), (true, false, _))
}

/// The declared layout's colours of a 2 x 2 pattern's cells, and whether the cells that
/// respond alike are its greens: where the other diagonal's are and the greens are not,
/// the layout is off by a row or a column (an offset or a row order the file did not
/// state, or a region read from an odd row).
fn declared_text(b: Bayer, r: &[f64], se: f64) -> String {
    let colours: Vec<String> = (0..4).map(|k| format!("{} {:.3}", b.colour(k).name(), r[k])).collect();
    let verdict = match diagonals(b, r, se) {
        (true, false, _) => "its greens respond alike, as a Bayer filter's do".to_string(),
        (false, true, [o0, o1]) => format!(
            "but the cells that respond alike are the other diagonal ({:.3} and {:.3}), not its greens: the layout is off by a row or a column (an offset or a row order the file does not state?)",
            r[o0], r[o1]
        ),
        _ => "the responses do not say which diagonal is green".to_string(),
    };
    format!("; the file declares {b} (BAYERPAT): {}; {verdict}", colours.join(", "))
}

/// For a 2 x 2 pattern whose one diagonal's two cells respond alike (within 5 standard
/// errors and 2%) and differ from both others: the Bayer arrangement it has, with "G" on
/// that diagonal (which of the other two is red the response cannot say).
fn bayer_text(r: &[f64], se: &f64) -> Option<String> {
    let (main, anti) = (alike(r[0], r[3], *se), alike(r[1], r[2], *se));
    let (g, others) = match (main, anti) {
        (true, false) => ((r[0] + r[3]) / 2.0, [r[1], r[2]]),
        (false, true) => ((r[1] + r[2]) / 2.0, [r[0], r[3]]),
        _ => return None,
    };
    let layout = if main {
        "GxxG (GRBG or GBRG)"
    } else {
        "xGGx (RGGB or BGGR)"
    };
    Some(format!("; one diagonal's two cells respond alike ({g:.3}, a Bayer filter's green, layout {layout}), the others {:.3} and {:.3}", others[0], others[1]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interaction of a Bayer table is `(2G - R - B) / 4` with alternating signs; a
    /// table of rows plus columns has none.
    #[test]
    fn the_interaction_of_a_bayer_table_is_its_green_excess() {
        let (g, r, b) = (1.23, 0.55, 0.99);
        let i = interaction(&[g, b, r, g], 2);
        let want = (2.0 * g - r - b) / 4.0;
        for (k, s) in [1.0, -1.0, -1.0, 1.0].iter().enumerate() {
            assert!((i[k] - s * want).abs() < 1e-12, "{i:?}");
        }
        let separable: Vec<f64> = (0..9)
            .map(|k| [0.1, 0.5, -0.2][k / 3] + [1.0, 2.0, 4.0][k % 3])
            .collect();
        assert!(interaction(&separable, 3).iter().all(|v| v.abs() < 1e-12));
    }

    /// The projection is the template's unit vector dotted with the other half in units
    /// of its standard error: a half equal to the template gives |I| / se.
    #[test]
    fn the_projection_is_the_matched_filter() {
        let a = [0.1, -0.1, -0.1, 0.1];
        assert!((projection(&a, &a, 0.01) - 20.0).abs() < 1e-9);
        assert!((projection(&a, &[0.1, 0.1, -0.1, -0.1], 0.01)).abs() < 1e-12);
        assert_eq!(projection(&[0.0; 4], &a, 0.01), 0.0);
        assert_eq!(
            alias(&[1.0, 2.0, 3.0, 4.0], 2, 4),
            vec![1.0, 2.0, 1.0, 2.0, 3.0, 4.0, 3.0, 4.0, 1.0, 2.0, 1.0, 2.0, 3.0, 4.0, 3.0, 4.0]
        );
    }

    #[test]
    fn a_bayer_diagonal_is_named_and_a_flat_table_is_not() {
        assert!(bayer_text(&[1.23, 0.99, 0.55, 1.23], &0.001)
            .is_some_and(|t| t.contains("GxxG") && t.contains("1.230")));
        assert!(bayer_text(&[0.55, 1.23, 1.23, 0.99], &0.001).is_some_and(|t| t.contains("xGGx")));
        assert!(bayer_text(&[1.0, 1.0, 1.0, 1.0], &0.001).is_none());
    }

    /// A declared layout names each cell's colour; its greens alike is a Bayer filter, the
    /// other diagonal alike instead is a layout off by a row or column.
    #[test]
    fn a_declared_layout_is_named_and_checked() {
        let r = [1.23, 0.99, 0.55, 1.23];
        let right = declared_text(Bayer::Gbrg, &r, 0.001);
        assert!(right.contains("green 1.230, blue 0.990, red 0.550, green 1.230") && right.contains("its greens respond alike"), "{right}");
        let off = declared_text(Bayer::Rggb, &r, 0.001);
        assert!(off.contains("red 1.230") && off.contains("the other diagonal (1.230 and 1.230)"), "{off}");
        assert!(declared_text(Bayer::Rggb, &[1.0; 4], 0.001).contains("do not say which diagonal"));
    }
}
