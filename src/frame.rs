//! The coordinate frame of a scan: which of its axes points up, and the turn between the two
//! conventions (+Y up for glTF and the preview camera, +Z up for most scanners and CAD).
//!
//! Input: a vector in one frame and the input's [`UpAxis`]. Output: the vector in the other
//! frame. Both turns are proper rotations about X by ±90°, (x, y, z) ↦ (x, z, −y) towards Y-up and
//! (x, y, z) ↦ (x, −z, y) back, so they keep lengths and handedness and undo each other exactly.

/// Which input axis points up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum UpAxis {
    /// The input is already +Y up (glTF's convention): coordinates are written unchanged.
    #[default]
    Y,
    /// The input is +Z up (most scanners and CAD): rotate by −90° about X, (x, y, z) ↦ (x, z, −y),
    /// so the object stands upright in Blender and other glTF viewers.
    Z,
}

impl UpAxis {
    /// `v`, given in an input frame with this up axis, in the +Y-up frame.
    pub(crate) fn input_to_y_up(self, v: [f64; 3]) -> [f64; 3] {
        match self {
            UpAxis::Y => v,
            UpAxis::Z => [v[0], v[2], -v[1]],
        }
    }

    /// `v`, given in the +Y-up frame, in an input frame with this up axis (the inverse of
    /// [`UpAxis::input_to_y_up`]).
    pub(crate) fn y_up_to_input(self, v: [f64; 3]) -> [f64; 3] {
        match self {
            UpAxis::Y => v,
            UpAxis::Z => [v[0], -v[2], v[1]],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_turns_undo_each_other() {
        assert_eq!(UpAxis::Z.input_to_y_up([1.0, 2.0, 3.0]), [1.0, 3.0, -2.0]);
        assert_eq!(UpAxis::Z.y_up_to_input([1.0, 3.0, -2.0]), [1.0, 2.0, 3.0]);
        assert_eq!(UpAxis::Y.input_to_y_up([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
        assert_eq!(UpAxis::Y.y_up_to_input([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
    }
}
