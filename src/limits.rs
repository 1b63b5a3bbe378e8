//! The numeric parameters' ranges: the [`Range`] type and one constant per command-line flag,
//! which the Python package checks its keyword arguments against too.
//!
//! Input: a number (or its text). Output: the number, or a message naming the flag or argument
//! and its range.
//!
//! A flag's value parser checks the value against its constant while clap parses the command
//! line (before any work; a value out of range is a usage error, exit code 2, naming the flag and
//! the range), and its help text prints the range from the same constant, so the two cannot
//! disagree. Negative numbers are taken as values (`--kappa -1` means `--kappa=-1`) and then
//! rejected by the range, not by clap's "use `-- -1`" tip.

/// The values a numeric flag accepts, both ends included.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    /// The flag as the user types it, for messages (`--degree`).
    pub flag: &'static str,
    /// Smallest accepted value.
    pub min: f64,
    /// Largest accepted value.
    pub max: f64,
    /// Whether only whole numbers are accepted.
    pub integer: bool,
}

impl Range {
    const fn int(flag: &'static str, min: u32, max: u32) -> Range {
        Range {
            flag,
            min: min as f64,
            max: max as f64,
            integer: true,
        }
    }

    const fn float(flag: &'static str, min: f64, max: f64) -> Range {
        Range {
            flag,
            min,
            max,
            integer: false,
        }
    }

    /// The range as the help and the errors print it: `2 to 14`, `1e-4 to 0.5`.
    pub fn describe(&self) -> String {
        format!("{} to {}", number(self.min), number(self.max))
    }

    /// A flag's help: `what` followed by `[range: …]` (clap adds `[default: …]` after it).
    pub fn help(&self, what: &str) -> String {
        format!("{what} [range: {}]", self.describe())
    }

    fn error(&self, text: &str) -> String {
        let kind = if self.integer {
            "a whole number"
        } else {
            "a number"
        };
        format!(
            "{} takes {kind} from {}, got '{text}'",
            self.flag,
            self.describe()
        )
    }

    /// `value`, given as the argument `name` (the Python package's keyword), when it lies in the
    /// range (and is whole, for an integer range); else a message naming `name` and the range.
    ///
    /// ```
    /// use stablesurf::limits::DEPTH;
    /// assert_eq!(DEPTH.check_value("depth", 7.0), Ok(7.0));
    /// assert_eq!(
    ///     DEPTH.check_value("depth", 13.0).unwrap_err(),
    ///     "depth takes a whole number from 1 to 12, got 13"
    /// );
    /// ```
    ///
    /// # Errors
    /// The message, when `value` is out of range, not finite or not whole.
    pub fn check_value(&self, name: &str, value: f64) -> Result<f64, String> {
        let whole = !self.integer || value.fract() == 0.0;
        if whole && value >= self.min && value <= self.max {
            return Ok(value);
        }
        let kind = if self.integer {
            "a whole number"
        } else {
            "a number"
        };
        Err(format!(
            "{name} takes {kind} from {}, got {value}",
            self.describe()
        ))
    }

    /// `text` as a number within the range.
    pub fn check_f64(&self, text: &str) -> Result<f64, String> {
        let t = text.trim();
        let value = if self.integer {
            t.parse::<i64>().ok().map(|v| v as f64)
        } else {
            t.parse::<f64>().ok()
        };
        match value {
            Some(v) if v >= self.min && v <= self.max => Ok(v),
            _ => Err(self.error(text)),
        }
    }

    /// A clap value parser for a whole-number flag of type `T`.
    pub fn whole<T: TryFrom<i64> + Clone + Send + Sync + 'static>(
        self,
    ) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static {
        move |text: &str| {
            let v = self.check_f64(text)?;
            T::try_from(v as i64).map_err(|_| self.error(text))
        }
    }

    /// A clap value parser for a real-number flag.
    pub fn real(self) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
        move |text: &str| self.check_f64(text)
    }
}

/// `x` as the help prints it: whole numbers plainly, very small or large ones as `1e-4`.
pub fn number(x: f64) -> String {
    if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e6) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// `-j`: worker threads. Results do not depend on the count, so more threads than cores only
/// add switching; 256 is far above any machine this runs on and far below the per-user
/// process limits (`-j 100000` used to fail while spawning threads).
pub const THREADS: Range = Range::int("-j/--threads", 1, 256);
/// `--degree`: 2 (a quadric) to 14. The fitter accepts 1 to `fit::MAX_DEGREE` (20), but degree
/// 1 is a plane (it bounds nothing), and past 14 (680 coefficients) the monomial basis is badly
/// conditioned and a fit takes minutes (degree 20 took 159 s on one scan).
pub const DEGREE: Range = Range::int("--degree", 2, 14);
/// `--kappa` when a number: κ weighs the ridge term κD against MᵀM (D is scaled like MᵀM's
/// diagonal, so κ = 1 already weighs them alike). Automatic κ searches 0 and 1e-8 … 1; 1000
/// leaves three decades above that, and values near 1e308 overflowed κD.
pub const KAPPA: Range = Range::float("--kappa", 0.0, 1e3);
/// `--epsilon`: the 3L layer offset in normalized units (the data's mean distance to its
/// centroid is 1; the paper uses 0.01 to 0.05). Below 1e-4 the three layers coincide in double
/// precision; at 0.5 the layers are half the shape's radius apart.
pub const EPSILON: Range = Range::float("--epsilon", 1e-4, 0.5);
/// `--local-degree`: the detail fit's local polynomials.
pub const LOCAL_DEGREE: Range = Range::int("--local-degree", 2, 4);
/// `--fit-stride`: detail mode fits every N-th point; past a few thousand a scan's fit keeps
/// too few points per ball for any surface the mesh can show.
pub const FIT_STRIDE: Range = Range::int("--fit-stride", 1, 4096);
/// `--tolerance`: a fraction of the bounding-box diagonal; at 0.5 no cell ever splits, and the
/// split depth is capped by the detail fit's `max_depth` however small it is.
pub const TOLERANCE: Range = Range::float("--tolerance", 1e-6, 0.5);
/// `--smooth`: a factor on the measured noise; 0 takes the points as exact, and at 10 the
/// local fits average a scatter ten times the data's, which flattens every feature of that size.
pub const SMOOTH: Range = Range::float("--smooth", 0.0, 10.0);
/// `--depth` (run, mesh, slices): octree depth near the surface; each level has about 4× the
/// triangles of the one before, so 12 is already ~4^5 times the default 7.
pub const DEPTH: Range = Range::int("--depth", 1, 12);
/// `--target-triangles` (run, mesh): the decimation's budget. 0 asks for no mesh at all; a
/// closed mesh cannot go below 4 (a tetrahedron), and the decimation says so when it stops
/// above the budget. A billion is far above any mesh the octree makes.
pub const TARGET_TRIANGLES: Range = Range::int("--target-triangles", 1, 1_000_000_000);
/// `slices --count`: slices across the box.
pub const COUNT: Range = Range::int("--count", 1, 1024);
/// `run --slice-count`: the same range as `slices --count`.
pub const SLICE_COUNT: Range = Range {
    flag: "--slice-count",
    ..COUNT
};
/// `slices --resolution`: pixels per side of a slice. 4096² is 16.8 million pixels (64 MiB of
/// float32) per slice.
pub const RESOLUTION: Range = Range::int("--resolution", 2, 4096);
/// `run --slice-resolution`: the same range as `slices --resolution`.
pub const SLICE_RESOLUTION: Range = Range {
    flag: "--slice-resolution",
    ..RESOLUTION
};
/// `--viewpoint X,Y,Z`: each coordinate of the sensor's position, as large as `--bounds` allows.
pub const VIEWPOINT: Range = Range::float("--viewpoint", -BOUNDS_MAX_ABS, BOUNDS_MAX_ABS);
/// `render --size`: image width and height in pixels.
pub const SIZE: Range = Range::int("--size", 16, 8192);
/// `--bounds`: largest magnitude of a coordinate; beyond it the box's diagonal and the octree's
/// cell sizes lose meaning in double precision (1e308 overflowed).
pub const BOUNDS_MAX_ABS: f64 = 1e15;

/// `--trim` as a number: the support factor (a triangle is kept when a data point lies within
/// this many local sample spacings of it).
pub const TRIM: Range = Range::float("--trim", 0.5, 100.0);
/// `--voxel-size`: the volumes' voxel edge, input units (the grid's own limit of 4096 voxels
/// per axis is checked against the meshing box at run time).
pub const VOXEL_SIZE: Range = Range::float("--voxel-size", 1e-9, BOUNDS_MAX_ABS);
