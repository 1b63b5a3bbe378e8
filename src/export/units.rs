//! Export stage, length units: the unit the input's coordinates are in, and its size in metres.
//!
//! Input: the unit a user names (`--units mm|cm|m|in|ft`). Output: the factor that turns input
//! coordinates into metres, which the glTF writers apply (glTF's unit is the metre, so a
//! millimetre scan written unscaled imports into Blender a thousand times too large), and the
//! symbol that the PLY header (`comment units mm`), the OpenEXR slice headers and report.json
//! record. Every other output (PLY coordinates, distances, model files) stays in input units.
//!
//! Invariant: without a unit nothing is scaled or recorded, so outputs are byte-identical to
//! those of a run that never heard of units.

use serde::{Deserialize, Serialize};

/// A length unit of input coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LengthUnit {
    /// Millimetre, 0.001 m (medical and industrial scanners, CAD).
    Mm,
    /// Centimetre, 0.01 m.
    Cm,
    /// Metre (LiDAR, terrestrial scanners, glTF's own unit).
    M,
    /// International inch, 0.0254 m.
    In,
    /// International foot, 0.3048 m.
    Ft,
}

impl LengthUnit {
    /// The unit's length in metres (exact by definition for all five).
    pub(crate) fn metres(self) -> f64 {
        match self {
            LengthUnit::Mm => 0.001,
            LengthUnit::Cm => 0.01,
            LengthUnit::M => 1.0,
            LengthUnit::In => 0.0254,
            LengthUnit::Ft => 0.3048,
        }
    }

    /// The unit's symbol, as `--units` takes it and the outputs record it.
    pub(crate) fn symbol(self) -> &'static str {
        match self {
            LengthUnit::Mm => "mm",
            LengthUnit::Cm => "cm",
            LengthUnit::M => "m",
            LengthUnit::In => "in",
            LengthUnit::Ft => "ft",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn factors_and_symbols() {
        assert_eq!(LengthUnit::Mm.metres(), 0.001);
        // 12 in = 1 ft, to the rounding of the product.
        assert!((LengthUnit::In.metres() * 12.0 - LengthUnit::Ft.metres()).abs() < 1e-15);
        for u in [
            LengthUnit::Mm,
            LengthUnit::Cm,
            LengthUnit::M,
            LengthUnit::In,
            LengthUnit::Ft,
        ] {
            // The serde name is the symbol (report.json).
            assert_eq!(
                serde_json::to_value(u).unwrap(),
                serde_json::Value::from(u.symbol())
            );
        }
    }
}
