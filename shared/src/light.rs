//! The light model shared by authoring and appliance: units and the bound check.
//!
//! Irradiance is stored in lux throughout (see ARCHITECTURE.md, "Units and frames").

/// One lux-hour: the unit of cumulative exposure budgets (CIE 157:2004).
pub const SECONDS_PER_HOUR: f64 = 3600.0;

/// Exposure in lux-hours of `lux` held for `seconds`.
pub fn lux_hours(lux: f64, seconds: f64) -> f64 {
    lux * seconds / SECONDS_PER_HOUR
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reciprocity_of_exposure() {
        // 50 lx for 10 h equals 250 lx for 2 h (the brief's damage-by-product rule).
        assert!((lux_hours(50.0, 36_000.0) - lux_hours(250.0, 7_200.0)).abs() < 1e-9);
    }
}
