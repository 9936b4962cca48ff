//! Summary statistics of measurements (timings, jitter, errors): the nearest-rank
//! percentile every report uses.

/// The `q` quantile (`0 ≤ q ≤ 1`) of `values` by nearest rank: sorts `values` in place
/// (ascending by [`f64::total_cmp`], so NaNs sort last) and returns the value at index
/// `round((n − 1) q)`. NaN when `values` is empty. Several quantiles of one set may be
/// taken in turn: the later sorts find the values already in order.
pub fn percentile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q).round() as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_of_the_sorted_values() {
        let mut v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(percentile(&mut v, 0.0), 1.0);
        assert_eq!(percentile(&mut v, 0.5), 3.0);
        assert_eq!(percentile(&mut v, 1.0), 5.0);
        // (n − 1) q = 3.6 rounds to index 4.
        assert_eq!(percentile(&mut v, 0.9), 5.0);
        assert_eq!(v, [1.0, 2.0, 3.0, 4.0, 5.0]);
        // A half rank rounds away from zero: index 0.5 -> 1.
        assert_eq!(percentile(&mut [2.0, 1.0], 0.5), 2.0);
    }

    #[test]
    fn empty_is_nan_and_one_value_is_every_quantile() {
        assert!(percentile(&mut [], 0.5).is_nan());
        assert_eq!(percentile(&mut [7.0], 0.0), 7.0);
        assert_eq!(percentile(&mut [7.0], 0.99), 7.0);
    }
}
