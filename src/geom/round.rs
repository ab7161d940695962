//! Rounding to whole numbers without a libm call: the baseline x86-64
//! target has no rounding instruction, so `f64::floor` is a function call,
//! and the raster and the horizon round in their innermost loops. Also the
//! least and greatest of two numbers in one instruction each, where
//! `f64::min` and `f64::max` spend several on NaN rules the caller does not
//! need. And a float as an integer of the same order, for sorting and
//! heaps keyed by depth, where integer compares cost less.

/// The smaller of `a` and `b`, for an `a` that is not NaN (a running
/// minimum started at +∞): then exactly `a.min(b)`, a NaN `b` included.
#[inline]
pub fn lesser(a: f64, b: f64) -> f64 {
    if b < a { b } else { a }
}

/// The larger of `a` and `b`, for an `a` that is not NaN: then exactly
/// `a.max(b)`, a NaN `b` included.
#[inline]
pub fn greater(a: f64, b: f64) -> f64 {
    if b > a { b } else { a }
}

/// `⌈x⌉` for finite `x`, saturating at the ends of `i64` (NaN gives 0:
/// callers rule it out first).
#[inline]
pub fn ceil_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) < x {
        i.saturating_add(1)
    } else {
        i
    }
}

/// `⌊x⌋` for finite `x`, saturating at the ends of `i64` (NaN gives 0:
/// callers rule it out first).
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i.saturating_sub(1)
    } else {
        i
    }
}

/// `x` as an unsigned integer ordered as `f64::total_cmp` orders the
/// floats: `ordered_bits(a) < ordered_bits(b)` exactly when `a` comes
/// before `b` (−NaN < −∞ < … < −0 < +0 < … < +∞ < NaN).
#[inline]
pub fn ordered_bits(x: f64) -> u64 {
    // `total_cmp`'s own mapping to a signed integer, moved to unsigned.
    let bits = x.to_bits() as i64;
    let ordered = bits ^ (((bits >> 63) as u64) >> 1) as i64;
    (ordered as u64) ^ (1 << 63)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordered_bits_order_as_total_cmp() {
        let values = [
            -f64::NAN,
            f64::NEG_INFINITY,
            -f64::MAX,
            -1.5,
            -f64::MIN_POSITIVE,
            -1e-310,
            -0.0,
            0.0,
            1e-310,
            f64::MIN_POSITIVE,
            1.0,
            1.0 + f64::EPSILON,
            f64::MAX,
            f64::INFINITY,
            f64::NAN,
        ];
        for a in values {
            for b in values {
                assert_eq!(
                    ordered_bits(a).cmp(&ordered_bits(b)),
                    a.total_cmp(&b),
                    "{a} {b}"
                );
            }
        }
    }

    #[test]
    fn lesser_and_greater_are_min_and_max_for_a_number_first() {
        let values = [
            f64::NEG_INFINITY,
            -1.5,
            -0.0,
            0.0,
            2.0,
            f64::INFINITY,
            f64::NAN,
        ];
        for a in values.into_iter().filter(|a| !a.is_nan()) {
            for b in values {
                // Rust leaves the sign of min/max(0.0, -0.0) open (and the
                // optimizer folds it either way): zeros compare by value.
                let same = |x: f64, y: f64| x.to_bits() == y.to_bits() || (x == 0.0 && y == 0.0);
                assert!(same(lesser(a, b), a.min(b)), "{a} {b}");
                assert!(same(greater(a, b), a.max(b)), "{a} {b}");
            }
        }
    }

    #[test]
    fn they_round_as_libm_does_and_saturate() {
        for x in [
            -2.5,
            -2.0,
            -0.5,
            -0.0,
            0.0,
            0.25,
            1.0,
            1.5,
            1e15 + 0.5,
            -1e15 - 0.5,
        ] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
            assert_eq!(ceil_i64(x), x.ceil() as i64, "{x}");
        }
        assert_eq!(floor_i64(1e300), i64::MAX);
        assert_eq!(ceil_i64(-1e300), i64::MIN);
        assert_eq!(floor_i64(f64::INFINITY), i64::MAX);
        assert_eq!(ceil_i64(f64::NEG_INFINITY), i64::MIN);
    }
}
