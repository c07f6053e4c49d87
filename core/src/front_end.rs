//! Steps 1–2 of the method for one sweep: intensity calibration (the range image, normals and
//! incidence angles) and the selection of edge, plane and intensity points. Independent of the
//! motion, so it runs on a thread of its own ahead of the odometry.

use crate::calibration::RangeImage;
use crate::config::OdometryConfig;
use crate::features::{FeatureSelector, SweepFeatures};
use crate::scan::Scan;

/// Steps 1–2 for one sweep, reusing its buffers from sweep to sweep.
#[derive(Debug, Default)]
pub struct FrontEnd {
    config: OdometryConfig,
    image: RangeImage,
    selector: FeatureSelector,
}

impl FrontEnd {
    /// A front end with the calibration and feature sections of `config`.
    pub fn new(config: &OdometryConfig) -> Self {
        Self {
            config: config.clone(),
            ..Self::default()
        }
    }

    /// Calibrates `scan` and selects its features into `out`.
    pub fn process(&mut self, scan: &Scan<'_>, out: &mut SweepFeatures) {
        self.image.build(scan, &self.config.calibration);
        self.selector
            .select(scan, &self.image, &self.config.features, out);
    }

    /// Return `i` of the scan last processed: its calibrated reflectivity η, NaN where it has
    /// none (see [`RangeImage::calibrated`]).
    pub fn calibrated(&self, i: usize) -> f32 {
        self.image.calibrated(i)
    }
}
