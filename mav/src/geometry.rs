//! Obstacles: vertical cylinders standing on the ground, and the ground itself.

/// `obstacle_index` used for the ground in collision reports.
pub const GROUND_INDEX: u32 = u32::MAX;

/// A vertical cylinder from the ground (z = 0) up to `height_m`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cylinder {
    pub x_m: f64,
    pub y_m: f64,
    pub radius_m: f64,
    #[serde(default = "Cylinder::default_height_m")]
    pub height_m: f64,
}

impl Cylinder {
    /// `docs/spec.md`: `zo = 10 m`.
    pub const PAPER_HEIGHT_M: f64 = 10.0;

    fn default_height_m() -> f64 {
        Self::PAPER_HEIGHT_M
    }

    pub fn new(x_m: f64, y_m: f64, radius_m: f64) -> Self {
        Self { x_m, y_m, radius_m, height_m: Self::PAPER_HEIGHT_M }
    }

    /// Names the first bad field.
    pub fn validate(&self) -> Result<(), &'static str> {
        if !self.x_m.is_finite() {
            return Err("x_m");
        }
        if !self.y_m.is_finite() {
            return Err("y_m");
        }
        if !self.radius_m.is_finite() || self.radius_m <= 0.0 {
            return Err("radius_m");
        }
        if !self.height_m.is_finite() || self.height_m <= 0.0 {
            return Err("height_m");
        }
        Ok(())
    }

    /// Horizontal distance from the axis.
    #[inline]
    pub fn axis_distance_m(&self, px: f64, py: f64) -> f64 {
        (px - self.x_m).hypot(py - self.y_m)
    }

    /// Signed clearance of a point to the cylinder surface, negative inside.
    ///
    /// Below the top this is the horizontal clearance `d - r` of `docs/spec.md`; above the top it is
    /// the distance to the top cap (so flying over a short cylinder is not a collision).
    #[inline]
    pub fn clearance_m(&self, px: f64, py: f64, pz: f64) -> f64 {
        let radial = self.axis_distance_m(px, py) - self.radius_m;
        if pz <= self.height_m {
            radial
        } else {
            let above = pz - self.height_m;
            if radial <= 0.0 { above } else { radial.hypot(above) }
        }
    }
}

/// Smallest clearance of a point to any of `obstacles` (+inf when there are none), and which.
pub fn min_clearance(obstacles: &[Cylinder], px: f64, py: f64, pz: f64) -> (f64, Option<usize>) {
    let mut best = (f64::INFINITY, None);
    for (i, c) in obstacles.iter().enumerate() {
        let d = c.clearance_m(px, py, pz);
        if d < best.0 {
            best = (d, Some(i));
        }
    }
    best
}

#[cfg(test)]
mod tests;
