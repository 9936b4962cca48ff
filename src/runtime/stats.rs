//! Percentiles of measured values (timings, errors) for status lines and benchmarks.

/// The `q`-quantile of `values` (0 ≤ q ≤ 1) by nearest rank on the sorted values: the
/// element at `round((n − 1)·q)` once sorted (`values` is sorted in place). NaN when
/// empty.
pub fn percentile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize]
}
