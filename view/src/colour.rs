//! Colours: calibrated reflectivity to a colour ramp, and the feature classes' colours.

/// Stops of the reflectivity ramp, from η = 0 (dark blue: black plastic, tyres) through
/// teal and green to yellow (η ≥ 1: white paint, retro-reflective tape). Monotonic in
/// lightness, so it reads in grey too.
const RAMP: [(f32, [f32; 3]); 5] = [
    (0.0, [30.0, 20.0, 90.0]),
    (0.25, [40.0, 90.0, 160.0]),
    (0.5, [30.0, 160.0, 140.0]),
    (0.75, [140.0, 210.0, 70.0]),
    (1.0, [250.0, 235.0, 40.0]),
];

/// A return whose reflectivity could not be calibrated (no surface normal, a weak return).
pub const UNCALIBRATED: [u8; 3] = [128, 128, 128];

/// The ramp's colour for calibrated reflectivity `eta` (about 0–1; clamped), grey for NaN.
pub fn reflectivity(eta: f32) -> [u8; 3] {
    if !eta.is_finite() {
        return UNCALIBRATED;
    }
    let x = eta.clamp(0.0, 1.0);
    let upper = RAMP
        .iter()
        .position(|(at, _)| *at >= x)
        .unwrap_or(RAMP.len() - 1);
    let (hi_at, hi) = RAMP[upper];
    let (lo_at, lo) = RAMP[upper.saturating_sub(1)];
    let f = if hi_at > lo_at {
        (x - lo_at) / (hi_at - lo_at)
    } else {
        0.0
    };
    std::array::from_fn(|i| (lo[i] + f * (hi[i] - lo[i])).round() as u8)
}

/// Feature classes, as logged in the annotation context of `world`: id, label, colour.
pub const CLASSES: [(u16, &str, [u8; 3]); 3] = [
    (1, "edge", [230, 60, 50]),
    (2, "plane", [70, 130, 230]),
    (3, "intensity", [250, 170, 30]),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ramp_runs_from_dark_to_light_and_clamps() {
        let lightness = |c: [u8; 3]| c.iter().map(|&v| v as u32).sum::<u32>();
        let mut last = 0;
        for i in 0..=20 {
            let l = lightness(reflectivity(i as f32 / 20.0));
            assert!(l >= last, "{i}");
            last = l;
        }
        assert_eq!(reflectivity(-3.0), reflectivity(0.0));
        assert_eq!(reflectivity(7.0), reflectivity(1.0));
        assert_eq!(reflectivity(1.0), [250, 235, 40]);
        assert_eq!(reflectivity(f32::NAN), UNCALIBRATED);
    }
}
