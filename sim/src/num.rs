//! Floor and fractional part without the library calls that `f64::floor` and `rem_euclid`
//! become on baseline x86-64 (which lacks a rounding instruction): hot loops call them for every
//! ray, in patterns, decal lookups, movers and the path lookup.

/// ⌊x⌋ for |x| < 2⁶² (scene coordinates and times are far below that).
#[inline]
pub(crate) fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// x − ⌊x⌋, in [0, 1).
#[inline]
pub(crate) fn fract(x: f64) -> f64 {
    let f = x - floor(x);
    if f >= 1.0 {
        0.0
    } else {
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn agrees_with_the_library() {
        for &x in &[
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.999_999,
            -2.999_999,
            1e9 + 0.25,
            -1e9 - 0.25,
            123.0,
            -123.0,
        ] {
            assert_eq!(floor(x), x.floor(), "{x}");
            assert_eq!(fract(x), x.rem_euclid(1.0), "{x}");
        }
        assert!(fract(-1e-20) < 1.0);
    }
}
