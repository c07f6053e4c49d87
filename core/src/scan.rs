//! What the odometry takes in: one sweep of returns in the sensor frame, each with its own
//! firing time. Plain data, filled by whoever decodes the sensor (the daemon, tests).

/// One return.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ScanPoint {
    /// Position in the sensor frame at the instant it was fired, m (REP-103).
    pub position: [f32; 3],
    /// Firing time, ns since the Unix epoch.
    pub time_ns: u64,
    /// The sensor's calibrated reflectivity: 0–100 diffuse, 101–255 retro-reflective.
    pub reflectivity: u8,
    /// Laser ring in elevation order (0 = lowest).
    pub ring: u8,
}

/// One sweep.
#[derive(Debug, Clone, Copy)]
pub struct Scan<'a> {
    /// Returns in firing order.
    pub points: &'a [ScanPoint],
    /// Number of rings of the sensor (16 for the VLP-16).
    pub rings: usize,
    /// The instant the sweep's pose describes (its last firing), ns since the epoch.
    pub reference_ns: u64,
}
