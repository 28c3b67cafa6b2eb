//! The populations of a linearity set's pixels by ADC: each ADC's median of a quantity,
//! their median, and the robust scatter about each pixel's own ADC median, computed
//! exactly in passes over the pixels. The steps of the diagnosis (the ADCs apart, the
//! camera's parameters, the pixel fits) each take them from here.

use crate::infra::select::Visit;

/// Per-ADC medians of the values `visit` gives (its cell is the value's ADC, below
/// `n_adc`) over items `0..n`, their median as the centre (one odd ADC does not move it),
/// and the robust scatter about each value's own ADC median (the pixel-to-pixel spread
/// alone). Exact, in passes over the items ([`crate::infra::select`]): no value is held (they
/// were 16 bytes a pixel at a time, and a diagnosis's peak).
pub(super) fn population(n: usize, n_adc: usize, visit: &Visit) -> (Vec<f64>, f64, f64) {
    let [one] = populations(n, n_adc, &|i, f| visit(i, &mut |a, x| f(0, a, x)));
    one
}

/// Visits the values of item `i`: `f(kind, adc, value)`.
pub(super) type Kinds<'a> = dyn Fn(usize, &mut dyn FnMut(usize, usize, f64)) + Sync + 'a;

/// [`population`] of `K` quantities at once (each pass over the items serves all).
pub(super) fn populations<const K: usize>(n: usize, n_adc: usize, visit: &Kinds) -> [(Vec<f64>, f64, f64); K] {
    let on = |k: usize, a: usize| k < K && a < n_adc;
    let per = crate::infra::select::upper_medians(n, K * n_adc, &|i, f| visit(i, &mut |k, a, x| if on(k, a) { f(k * n_adc + a, x) }));
    let scatter = crate::infra::select::robust(n, K, &|i, f| visit(i, &mut |k, a, x| if on(k, a) { f(k, x - per[k * n_adc + a]) }));
    std::array::from_fn(|k| {
        let per = per[k * n_adc..(k + 1) * n_adc].to_vec();
        // The textbook median here (four ADCs: the mean of the middle two), not the upper
        // one.
        let centre = crate::infra::stats::median(per.iter().copied());
        (per, centre, scatter[k].1)
    })
}
