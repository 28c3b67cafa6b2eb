//! Polynomials of the pixel-wise correction and their inversion `x = P^-1(m)`.
//!
//! The inversion runs for every pixel and level (43 M times on a 1024 x 1024 x 41 set).
//! Newton's iteration is a chain of dependent multiply-adds and a division, about 35
//! cycles a step, so one pixel at a time the processor waits on latency. [`invert_all`]
//! runs [`LANES`] pixels' iterations side by side, each lane doing exactly the steps
//! [`invert`] does (same operations in the same order, stopping at the same step), so
//! the results are bit for bit those of [`invert`]; lanes that leave the fast path (a
//! zero or non-finite slope, no convergence in a few steps) finish alone, from where they
//! stand, exactly as [`invert`] would go on.

/// `sum a_k x^k` (Horner).
pub fn poly(a: &[f64], x: f64) -> f64 {
    a.iter().rev().fold(0.0, |acc, &c| acc * x + c)
}

/// `d/dx sum a_k x^k`.
pub fn poly_slope(a: &[f64], x: f64) -> f64 {
    a.iter().enumerate().skip(1).rev().fold(0.0, |acc, (k, &c)| acc * x + k as f64 * c)
}

/// Newton steps at most, before the bisection fallback.
const NEWTON_STEPS: usize = 30;

/// Newton has converged when a step is below this, relative to `1 + |x|`: it converges
/// quadratically, so after a step of 1e-9 the error is about `(P''/2P') 1e-18`, below
/// f64's resolution of x (a further step moved nothing).
const STEP_TOLERANCE: f64 = 1e-9;

/// `x` with `P(x) = m`: Newton from `guess`, then bisection on [-0.5, 2] if Newton fails;
/// NaN when `P - m` does not change sign there.
pub fn invert(a: &[f64], m: f64, guess: f64) -> f64 {
    let mut x = guess;
    for _ in 0..NEWTON_STEPS {
        // Value and slope in one Horner pass (the slope by synthetic division).
        let (mut f, mut d) = (0.0, 0.0);
        for &c in a.iter().rev() {
            d = d * x + f;
            f = f * x + c;
        }
        f -= m;
        if d == 0.0 || !d.is_finite() {
            break;
        }
        let step = f / d;
        x -= step;
        if step.abs() < STEP_TOLERANCE * (1.0 + x.abs()) {
            return x;
        }
    }
    settle(a, m, x)
}

/// What [`invert`] makes of the point `x` where Newton stopped without converging: `x`
/// if it solves `P(x) = m` closely enough, else bisection on [-0.5, 2].
fn settle(a: &[f64], m: f64, x: f64) -> f64 {
    if (poly(a, x) - m).abs() <= 1e-9 * m.abs().max(1.0) {
        return x;
    }
    let (mut lo, mut hi) = (-0.5, 2.0);
    if (poly(a, lo) - m).signum() == (poly(a, hi) - m).signum() {
        return f64::NAN;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        // Once `lo` and `hi` are neighbouring doubles their midpoint rounds to one of
        // them and no further halving changes either: stopping here returns what the
        // remaining iterations would.
        if mid == lo || mid == hi {
            break;
        }
        if (poly(a, mid) - m).signum() == (poly(a, lo) - m).signum() { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

/// Newton steps side by side in a first round. A lane near its root converges in 3 or 4;
/// one that needs more (a mean beyond the polynomial's range, at a saturated level) is
/// set aside and goes on in a second round with the others set aside, so that it does
/// not hold a batch of converged lanes for all of [`NEWTON_STEPS`].
const FIRST_ROUND: usize = 6;
// `Batch::round` tells the rounds apart by their steps.
const _: () = assert!(FIRST_ROUND != NEWTON_STEPS - FIRST_ROUND);

/// Pixels inverted side by side (8 doubles: two AVX registers, four SSE ones; the
/// compiler keeps each lane's chain independent either way).
pub const LANES: usize = 8;

/// Where a lane's Newton iteration stands after a round.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Lane {
    /// No polynomial in this lane (a skipped pixel, or past the end of a short batch).
    Idle,
    Converged,
    /// A zero or non-finite slope: [`invert`] breaks out of Newton here.
    BrokeOff,
    /// Out of steps for this round.
    Running,
}

/// Up to `steps` Newton steps of [`invert`] in every lane of `x` that is `Running`, lane
/// `i` on `sum_k a[k][i] x^k = m[i]`; the same operations in the same order as
/// [`invert`]'s loop, branch-free per lane (the compiler turns the selects into blends).
fn newton_lanes(a: &[[f64; LANES]], m: &[f64; LANES], x: &mut [f64; LANES], state: &mut [Lane; LANES], steps: usize) {
    let mut done = state.map(|s| s != Lane::Running);
    let mut broke = [false; LANES];
    for _ in 0..steps {
        let (mut f, mut d) = ([0.0; LANES], [0.0; LANES]);
        for c in a.iter().rev() {
            for i in 0..LANES {
                d[i] = d[i] * x[i] + f[i];
                f[i] = f[i] * x[i] + c[i];
            }
        }
        for i in 0..LANES {
            let bad = d[i] == 0.0 || !d[i].is_finite();
            let step = (f[i] - m[i]) / d[i];
            let next = x[i] - step;
            let active = !done[i] & !bad;
            let converged = step.abs() < STEP_TOLERANCE * (1.0 + next.abs());
            x[i] = if active { next } else { x[i] };
            broke[i] |= !done[i] & bad;
            done[i] |= bad | (active & converged);
        }
        if done.iter().all(|&d| d) {
            break;
        }
    }
    for i in 0..LANES {
        if state[i] == Lane::Running && done[i] {
            state[i] = if broke[i] { Lane::BrokeOff } else { Lane::Converged };
        }
    }
}

/// [`invert`] of `out.len()` polynomials, [`LANES`] at a time: `out[j] = invert(a_j,
/// m(j), guess)` with `a_j[k] = coef(j, k)` (`k < order + 1 = k1`), NaN where `skip(j)`.
/// Bit for bit [`invert`] of each (test below).
pub fn invert_all(out: &mut [f64], k1: usize, guess: f64, coef: impl Fn(usize, usize) -> f64, m: impl Fn(usize) -> f64, skip: impl Fn(usize) -> bool) {
    let mut batch = Batch { a: vec![[0.0; LANES]; k1], coef, m, skip, aside: Vec::with_capacity(2 * LANES) };
    for first in (0..out.len()).step_by(LANES) {
        let mut js = [0; LANES];
        let n = LANES.min(out.len() - first);
        for (i, j) in js[..n].iter_mut().enumerate() {
            *j = first + i;
        }
        batch.round(out, &js[..n], [guess; LANES], FIRST_ROUND);
        if batch.aside.len() >= LANES {
            batch.second_round(out);
        }
    }
    while !batch.aside.is_empty() {
        batch.second_round(out);
    }
}

/// The state of [`invert_all`]: the coefficients of the lanes in flight, and the lanes
/// set aside after their first round (index, where Newton stands).
struct Batch<C, M, S> {
    a: Vec<[f64; LANES]>,
    coef: C,
    m: M,
    skip: S,
    aside: Vec<(usize, f64)>,
}

impl<C: Fn(usize, usize) -> f64, M: Fn(usize) -> f64, S: Fn(usize) -> bool> Batch<C, M, S> {
    /// Polynomials `js` (at most [`LANES`]) from `x`, `steps` Newton steps side by side;
    /// each result into `out`, or set aside when the first round leaves it running.
    fn round(&mut self, out: &mut [f64], js: &[usize], mut x: [f64; LANES], steps: usize) {
        let (mut ms, mut state) = ([0.0; LANES], [Lane::Idle; LANES]);
        for (i, &j) in js.iter().enumerate() {
            out[j] = f64::NAN;
            if (self.skip)(j) {
                continue;
            }
            for (k, c) in self.a.iter_mut().enumerate() {
                c[i] = (self.coef)(j, k);
            }
            (ms[i], state[i]) = ((self.m)(j), Lane::Running);
        }
        newton_lanes(&self.a, &ms, &mut x, &mut state, steps);
        for (i, &j) in js.iter().enumerate() {
            match state[i] {
                Lane::Idle => {}
                Lane::Converged => out[j] = x[i],
                Lane::Running if steps == FIRST_ROUND => self.aside.push((j, x[i])),
                // Broke off, or out of all of `invert`'s steps: its checks and bisection.
                Lane::BrokeOff | Lane::Running => {
                    let column: Vec<f64> = self.a.iter().map(|c| c[i]).collect();
                    out[j] = settle(&column, ms[i], x[i]);
                }
            }
        }
    }

    /// Up to [`LANES`] of the lanes set aside, through the rest of `invert`'s steps.
    fn second_round(&mut self, out: &mut [f64]) {
        let n = LANES.min(self.aside.len());
        let (mut js, mut x) = ([0; LANES], [0.0; LANES]);
        for (i, (j, xj)) in self.aside.drain(..n).enumerate() {
            (js[i], x[i]) = (j, xj);
        }
        self.round(out, &js[..n], x, NEWTON_STEPS - FIRST_ROUND);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn invert_solves_a_known_quartic() {
        // P(x) = 100 + 3000 x - 150 x^2 + 40 x^3 - 12 x^4 at x = 0.37, by hand.
        let a = [100.0, 3000.0, -150.0, 40.0, -12.0];
        let x: f64 = 0.37;
        let m = 100.0 + 3000.0 * x - 150.0 * x * x + 40.0 * x.powi(3) - 12.0 * x.powi(4);
        assert!((invert(&a, m, 0.5) - x).abs() < 1e-14);
        // No root on [-0.5, 2]: NaN, not a made-up value.
        assert!(invert(&[1.0, 0.0, 1.0], 0.0, 0.3).is_nan());
    }

    #[test]
    fn slow_lanes_are_set_aside_and_finish_as_invert_does() {
        // x^4 = m from x = 1: Newton shrinks the error by 3/4 a step, so these need
        // 8 to 30 steps (set aside, more than a batch of them, some out of all steps and
        // settled); quartics near their root converge in the first round between them.
        let slow = |j: usize| 10f64.powi(-(j as i32 % 12) - 1);
        let quartic = [100.0, 3000.0, -150.0, 40.0, -12.0];
        let n = 37;
        let coef = |j: usize, k: usize| if j.is_multiple_of(3) { quartic[k] } else if k == 4 { 1.0 } else { 0.0 };
        let m = |j: usize| if j.is_multiple_of(3) { 1500.0 + j as f64 } else { slow(j) };
        let mut got = vec![0.0; n];
        invert_all(&mut got, 5, 1.0, coef, m, |_| false);
        for (j, &g) in got.iter().enumerate() {
            let a: Vec<f64> = (0..5).map(|k| coef(j, k)).collect();
            let want = invert(&a, m(j), 1.0);
            assert!(g.to_bits() == want.to_bits() || (g.is_nan() && want.is_nan()), "{j}: {g} vs {want}");
            if j % 3 != 0 {
                // The root itself where Newton reaches it, m^(1/4).
                assert!(want.is_nan() || (want - m(j).powf(0.25)).abs() < 1e-3, "{j}: {want}");
            }
        }
    }

    proptest! {
        /// Side by side is bit for bit one at a time, including lanes that break off
        /// (constant polynomials), lanes set aside after the first round (roots far from
        /// the guess, or none), skipped ones and a last batch shorter than [`LANES`].
        #[test]
        fn all_equal_one_at_a_time(
            coeffs in proptest::collection::vec(proptest::collection::vec(-5000.0f64..5000.0, 1..9), 1..40),
            m in proptest::collection::vec(-100.0f64..5000.0, 40),
            guess in -0.2f64..1.2,
            skip in proptest::collection::vec(any::<bool>(), 40),
            flat in 0usize..40,
        ) {
            let n = coeffs.len();
            let k1 = coeffs.iter().map(Vec::len).min().unwrap_or(1);
            // One polynomial constant (zero slope everywhere: Newton cannot start).
            let coef = |j: usize, k: usize| if j == flat && k > 0 { 0.0 } else { coeffs[j][k] };
            let mut got = vec![0.0; n];
            invert_all(&mut got, k1, guess, coef, |j| m[j], |j| skip[j]);
            for j in 0..n {
                if skip[j] {
                    prop_assert!(got[j].is_nan());
                } else {
                    let a: Vec<f64> = (0..k1).map(|k| coef(j, k)).collect();
                    let want = invert(&a, m[j], guess);
                    prop_assert!(got[j].to_bits() == want.to_bits() || (got[j].is_nan() && want.is_nan()), "{j}: {} vs {}", got[j], want);
                }
            }
        }
    }
}
