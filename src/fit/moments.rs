//! The fit's sufficient statistics for one chunk of points, so that a global fit can be
//! computed from chunks processed apart (other processes, other machines) and merged.
//!
//! Input: an [`OrientedCloud`] chunk and a [`MomentsPass`]. Output: a [`PartialMoments`]
//! artifact, mergeable by plain summation and encoded as a small versioned binary
//! ([`PartialMoments::to_bytes`], [`PartialMoments::from_bytes`]; no IO here).
//!
//! The normalization frame (paper 2.2: μ the centroid, s the mean distance |p − μ|) depends on
//! every point, and the 3L rows p̂ ± εn depend on s (ε is in normalized units), so the moments
//! cannot be taken in a fixed frame and shifted exactly afterwards. The protocol is three passes
//! over the chunks, each cheap next to the fit and each merged in chunk order:
//!
//! ```text
//! pass 1  MomentsPass::Center        → N, Σp, box     ─ merge_frame ─▶ μ = Σp / N
//! pass 2  MomentsPass::Scale{μ}      → N, Σ|p − μ|     ─ merge_frame ─▶ s = Σ|p − μ| / N
//! pass 3  MomentsPass::System{μ,s,n,ε} → moments, Mᵀb, β, N, box ─ fit_from_moments ─▶ model
//! ```
//!
//! μ and s are the same sums [`super::fit`] computes over the whole cloud, added in another
//! order, so the merged system equals the whole fit's to rounding (measured: 8 chunks of a
//! torus, coefficients within 1e-12 relative; tests/all/fit.rs).
//!
//! What the moments cannot carry: the stable κ rule checks the zero set against the points, the
//! `ls` method signs its eigenvector with the normals, and the QR solver streams the rows, so
//! [`super::fit_from_moments`] takes a fixed κ or the paper's κ rule, the 3lrr or 3l method and
//! the moment solver. The model's first-order distances to the data are not measured (0, with
//! a warning). Outlier removal needs all points, so chunks are used as they are.
//!
//! File format (little-endian): the magic `SSMOMENT`, the format version (u32), the pass kind
//! (u8: 1 center, 2 scale, 3 system), the pass's fields, then the BLAKE3 hash of all bytes
//! before it (a corrupt or truncated file is refused).

use crate::cloud::{Aabb, OrientedCloud};

use super::system::{self, Normalization, Rows};
use super::FitError;

/// Version of the moments file format; bump it when the layout changes.
pub(crate) const MOMENTS_FORMAT_VERSION: u32 = 1;

const MAGIC: &[u8; 8] = b"SSMOMENT";
const HASH_LEN: usize = 32;
/// Points summed per group (the same grouping as the whole fit's normalization).
const GROUP: usize = 2048;

/// The normalization frame p̂ = (p − center)/scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// μ, the centroid of all points (input coordinates).
    pub center: [f64; 3],
    /// s, the mean distance of all points to μ (input units).
    pub scale: f64,
}

/// Which pass of the protocol to run on a chunk.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MomentsPass {
    /// Pass 1: point count, coordinate sums and box.
    Center,
    /// Pass 2: point count and the sum of distances to the merged centroid.
    Scale {
        /// μ from pass 1.
        center: [f64; 3],
    },
    /// Pass 3: the fit's moments in the merged frame.
    System {
        /// μ and s from passes 1 and 2.
        frame: Frame,
        /// Polynomial degree n.
        degree: u32,
        /// Layer offset ε in normalized units.
        epsilon: f64,
    },
}

/// The moments of pass 3 for one chunk (or a merged set of chunks).
#[derive(Clone, Debug, PartialEq)]
pub struct SystemMoments {
    /// Points summed.
    pub n_points: u64,
    /// Polynomial degree n.
    pub degree: u32,
    /// Layer offset ε (normalized units).
    pub epsilon: f64,
    /// The frame the rows were normalized in.
    pub frame: Frame,
    /// Box of the points (input coordinates).
    pub bounds: Aabb,
    /// Σ q^e over the 3L rows for every e of degree ≤ 2n, in the paper's graded order.
    pub moments: Vec<f64>,
    /// Mᵀb in the paper's order.
    pub rhs: Vec<f64>,
    /// β_r = Σ_t |p̂_t|^{2r}, r = 0 … n.
    pub beta: Vec<f64>,
}

/// One chunk's statistics for one pass.
#[derive(Clone, Debug, PartialEq)]
pub enum PartialMoments {
    /// Pass 1.
    Center {
        /// Points summed.
        n_points: u64,
        /// Σ p (input coordinates).
        sum: [f64; 3],
        /// Box of the points.
        bounds: Aabb,
    },
    /// Pass 2.
    Scale {
        /// Points summed.
        n_points: u64,
        /// The centroid the distances were taken to.
        center: [f64; 3],
        /// Σ |p − center|.
        sum_distance: f64,
    },
    /// Pass 3.
    System(SystemMoments),
}

/// The result of merging pass-1 or pass-2 files: the next pass's input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MergedFrame {
    /// From pass-1 files: μ (give it to pass 2).
    Center([f64; 3]),
    /// From pass-2 files: μ and s (give them to pass 3).
    Frame(Frame),
}

/// Errors of reading or merging moments files.
#[derive(Debug, thiserror::Error)]
pub enum MomentsError {
    /// Not a moments file.
    #[error("not a stablesurf moments file (no SSMOMENT header): give a file written by `stablesurf moments`")]
    NotMoments,
    /// Written by another format version.
    #[error("moments format version {found}, this build reads version {MOMENTS_FORMAT_VERSION}: recompute it with this build's `stablesurf moments`")]
    Version {
        /// The file's version.
        found: u32,
    },
    /// Truncated or damaged.
    #[error("the moments file is truncated or corrupt ({0}): copy it again or recompute it")]
    Corrupt(&'static str),
    /// Parts of different passes or frames given together.
    #[error("part {index} {what}: give parts of one pass, computed with the same frame, degree and epsilon")]
    Mismatch {
        /// Index of the offending part in the list.
        index: usize,
        /// What differs.
        what: String,
    },
    /// No part given.
    #[error("no moments files given")]
    Empty,
    /// All points coincide.
    #[error("all points coincide: the cloud has no extent to fit")]
    Degenerate,
}

/// Computes one pass's statistics over a chunk.
///
/// # Errors
/// Non-finite input, zero or missing normals ([`FitError`]), an empty chunk, or an invalid
/// degree, ε or frame.
pub fn moments(cloud: &OrientedCloud, pass: &MomentsPass) -> Result<PartialMoments, FitError> {
    if let MomentsPass::System {
        frame,
        degree,
        epsilon,
    } = *pass
    {
        super::check_degree_epsilon(degree, epsilon)?;
        if !(frame.scale.is_finite()
            && frame.scale > 0.0
            && frame.center.iter().all(|c| c.is_finite()))
        {
            return Err(FitError::DegenerateCloud);
        }
    }
    let degree = match *pass {
        MomentsPass::System { degree, .. } => degree,
        _ => 0,
    };
    let checked = super::validate(cloud, degree, 1)?;
    let cloud = checked.as_ref().unwrap_or(cloud);
    let n_points = cloud.points.len() as u64;
    let bounds = Aabb::from_points(&cloud.points).ok_or(FitError::DegenerateCloud)?;
    Ok(match *pass {
        MomentsPass::Center => {
            let mut sum = [0.0; 3];
            for group in cloud.points.chunks(GROUP) {
                let mut s = [0.0; 3];
                for p in group {
                    for a in 0..3 {
                        s[a] += p[a];
                    }
                }
                for a in 0..3 {
                    sum[a] += s[a];
                }
            }
            PartialMoments::Center {
                n_points,
                sum,
                bounds,
            }
        }
        MomentsPass::Scale { center } => {
            let mut sum_distance = 0.0;
            for group in cloud.points.chunks(GROUP) {
                sum_distance += group
                    .iter()
                    .map(|p| {
                        let d = [0, 1, 2].map(|a| p[a] - center[a]);
                        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                    })
                    .sum::<f64>();
            }
            PartialMoments::Scale {
                n_points,
                center,
                sum_distance,
            }
        }
        MomentsPass::System {
            frame,
            degree,
            epsilon,
        } => {
            let norm = Normalization {
                center: frame.center,
                scale: frame.scale,
            };
            let sys = system::accumulate(cloud, &norm, degree, Rows::ThreeLayers { epsilon });
            PartialMoments::System(SystemMoments {
                n_points,
                degree,
                epsilon,
                frame,
                bounds,
                moments: sys.moments,
                rhs: sys.rhs,
                beta: sys.beta,
            })
        }
    })
}

/// Merges pass-1 files into μ, or pass-2 files into μ and s, summing in the order given.
///
/// # Errors
/// No part, parts of different passes, pass-2 parts with different centres, pass-3 parts, or a
/// degenerate cloud.
pub fn merge_frame(parts: &[PartialMoments]) -> Result<MergedFrame, MomentsError> {
    let first = parts.first().ok_or(MomentsError::Empty)?;
    let mut n = 0u64;
    match first {
        PartialMoments::Center { .. } => {
            let mut total = [0.0; 3];
            for (index, part) in parts.iter().enumerate() {
                let PartialMoments::Center { n_points, sum, .. } = part else {
                    return Err(mismatch(index, "is not a pass-1 (center) file"));
                };
                n += n_points;
                for a in 0..3 {
                    total[a] += sum[a];
                }
            }
            let center = total.map(|c| c / n.max(1) as f64);
            Ok(MergedFrame::Center(center))
        }
        PartialMoments::Scale { center, .. } => {
            let center = *center;
            let mut total = 0.0;
            for (index, part) in parts.iter().enumerate() {
                let PartialMoments::Scale {
                    n_points,
                    center: c,
                    sum_distance,
                } = part
                else {
                    return Err(mismatch(index, "is not a pass-2 (scale) file"));
                };
                if *c != center {
                    return Err(mismatch(
                        index,
                        &format!("was computed with centre {c:?}, part 0 with {center:?}"),
                    ));
                }
                n += n_points;
                total += sum_distance;
            }
            let scale = total / n.max(1) as f64;
            if !(scale.is_finite() && scale > 0.0) {
                return Err(MomentsError::Degenerate);
            }
            Ok(MergedFrame::Frame(Frame { center, scale }))
        }
        PartialMoments::System(_) => Err(mismatch(
            0,
            "is a pass-3 (system) file, which `fit --from-moments` merges",
        )),
    }
}

/// Sums pass-3 parts (in the order given) after checking they share degree, ε and frame.
///
/// # Errors
/// No part, a part of another pass, or a mismatch.
pub fn merge_system(parts: &[PartialMoments]) -> Result<SystemMoments, MomentsError> {
    let Some(PartialMoments::System(first)) = parts.first() else {
        return Err(match parts.first() {
            None => MomentsError::Empty,
            Some(_) => mismatch(
                0,
                "is not a pass-3 (system) file: run `stablesurf moments --frame`",
            ),
        });
    };
    let mut total = first.clone();
    for (index, part) in parts.iter().enumerate().skip(1) {
        let PartialMoments::System(p) = part else {
            return Err(mismatch(index, "is not a pass-3 (system) file"));
        };
        if p.degree != first.degree {
            return Err(mismatch(
                index,
                &format!("has degree {}, part 0 degree {}", p.degree, first.degree),
            ));
        }
        if p.epsilon != first.epsilon {
            return Err(mismatch(
                index,
                &format!(
                    "has epsilon {}, part 0 epsilon {}",
                    p.epsilon, first.epsilon
                ),
            ));
        }
        if p.frame != first.frame {
            return Err(mismatch(
                index,
                &format!("has frame {:?}, part 0 frame {:?}", p.frame, first.frame),
            ));
        }
        if p.moments.len() != first.moments.len()
            || p.rhs.len() != first.rhs.len()
            || p.beta.len() != first.beta.len()
        {
            return Err(mismatch(index, "has sums of another length"));
        }
        total.n_points += p.n_points;
        for a in 0..3 {
            total.bounds.min[a] = total.bounds.min[a].min(p.bounds.min[a]);
            total.bounds.max[a] = total.bounds.max[a].max(p.bounds.max[a]);
        }
        for (t, v) in total.moments.iter_mut().zip(&p.moments) {
            *t += v;
        }
        for (t, v) in total.rhs.iter_mut().zip(&p.rhs) {
            *t += v;
        }
        for (t, v) in total.beta.iter_mut().zip(&p.beta) {
            *t += v;
        }
    }
    Ok(total)
}

fn mismatch(index: usize, what: &str) -> MomentsError {
    MomentsError::Mismatch {
        index,
        what: what.to_string(),
    }
}

impl MergedFrame {
    /// The value the next pass takes on the command line: `cx,cy,cz` (`--center`) or
    /// `cx,cy,cz,s` (`--frame`), printed so that it reads back to the same bits.
    pub fn argument(&self) -> String {
        match self {
            MergedFrame::Center(c) => format!("{:?},{:?},{:?}", c[0], c[1], c[2]),
            MergedFrame::Frame(f) => format!(
                "{:?},{:?},{:?},{:?}",
                f.center[0], f.center[1], f.center[2], f.scale
            ),
        }
    }
}

impl PartialMoments {
    /// The file bytes: header, fields, BLAKE3 hash.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&MOMENTS_FORMAT_VERSION.to_le_bytes());
        let f = |out: &mut Vec<u8>, v: f64| out.extend_from_slice(&v.to_le_bytes());
        let b = |out: &mut Vec<u8>, bx: &Aabb| {
            for v in bx.min.iter().chain(&bx.max) {
                out.extend_from_slice(&v.to_le_bytes());
            }
        };
        match self {
            PartialMoments::Center {
                n_points,
                sum,
                bounds,
            } => {
                out.push(1);
                out.extend_from_slice(&n_points.to_le_bytes());
                sum.iter().for_each(|&v| f(&mut out, v));
                b(&mut out, bounds);
            }
            PartialMoments::Scale {
                n_points,
                center,
                sum_distance,
            } => {
                out.push(2);
                out.extend_from_slice(&n_points.to_le_bytes());
                center.iter().for_each(|&v| f(&mut out, v));
                f(&mut out, *sum_distance);
            }
            PartialMoments::System(s) => {
                out.push(3);
                out.extend_from_slice(&s.n_points.to_le_bytes());
                out.extend_from_slice(&s.degree.to_le_bytes());
                f(&mut out, s.epsilon);
                s.frame.center.iter().for_each(|&v| f(&mut out, v));
                f(&mut out, s.frame.scale);
                b(&mut out, &s.bounds);
                for list in [&s.moments, &s.rhs, &s.beta] {
                    out.extend_from_slice(&(list.len() as u64).to_le_bytes());
                    list.iter().for_each(|&v| f(&mut out, v));
                }
            }
        }
        let hash = blake3::hash(&out);
        out.extend_from_slice(hash.as_bytes());
        out
    }

    /// Reads file bytes written by [`PartialMoments::to_bytes`].
    ///
    /// # Errors
    /// Not a moments file, another format version, or a truncated or corrupt file.
    pub fn from_bytes(bytes: &[u8]) -> Result<PartialMoments, MomentsError> {
        if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
            return Err(MomentsError::NotMoments);
        }
        if bytes.len() < MAGIC.len() + 4 + 1 + HASH_LEN {
            return Err(MomentsError::Corrupt("too short"));
        }
        let mut version = [0u8; 4];
        version.copy_from_slice(&bytes[8..12]);
        let version = u32::from_le_bytes(version);
        if version != MOMENTS_FORMAT_VERSION {
            return Err(MomentsError::Version { found: version });
        }
        let (body, hash) = bytes.split_at(bytes.len() - HASH_LEN);
        if blake3::hash(body).as_bytes() != hash {
            return Err(MomentsError::Corrupt("checksum mismatch"));
        }
        let mut r = Reader {
            bytes: body,
            at: 12,
        };
        let kind = r.take(1)?[0];
        let part = match kind {
            1 => PartialMoments::Center {
                n_points: r.u64()?,
                sum: r.f3()?,
                bounds: r.aabb()?,
            },
            2 => PartialMoments::Scale {
                n_points: r.u64()?,
                center: r.f3()?,
                sum_distance: r.f64()?,
            },
            3 => {
                let n_points = r.u64()?;
                let degree = r.u32()?;
                if degree == 0 || degree > super::MAX_DEGREE {
                    return Err(MomentsError::Corrupt("degree out of range"));
                }
                let epsilon = r.f64()?;
                let center = r.f3()?;
                let scale = r.f64()?;
                let bounds = r.aabb()?;
                let n = degree as usize;
                let moments = r.list(crate::poly::n_coefficients(2 * degree))?;
                let rhs = r.list(crate::poly::n_coefficients(degree))?;
                let beta = r.list(n + 1)?;
                PartialMoments::System(SystemMoments {
                    n_points,
                    degree,
                    epsilon,
                    frame: Frame { center, scale },
                    bounds,
                    moments,
                    rhs,
                    beta,
                })
            }
            _ => return Err(MomentsError::Corrupt("unknown pass kind")),
        };
        if r.at != body.len() {
            return Err(MomentsError::Corrupt("trailing bytes"));
        }
        Ok(part)
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], MomentsError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or(MomentsError::Corrupt("truncated"))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self) -> Result<u64, MomentsError> {
        let mut a = [0u8; 8];
        a.copy_from_slice(self.take(8)?);
        Ok(u64::from_le_bytes(a))
    }
    fn u32(&mut self) -> Result<u32, MomentsError> {
        let mut a = [0u8; 4];
        a.copy_from_slice(self.take(4)?);
        Ok(u32::from_le_bytes(a))
    }
    fn f64(&mut self) -> Result<f64, MomentsError> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn f3(&mut self) -> Result<[f64; 3], MomentsError> {
        Ok([self.f64()?, self.f64()?, self.f64()?])
    }
    fn aabb(&mut self) -> Result<Aabb, MomentsError> {
        Ok(Aabb {
            min: self.f3()?,
            max: self.f3()?,
        })
    }
    fn list(&mut self, expected: usize) -> Result<Vec<f64>, MomentsError> {
        let len = self.u64()?;
        if len != expected as u64 {
            return Err(MomentsError::Corrupt(
                "a list has the wrong length for its degree",
            ));
        }
        (0..expected).map(|_| self.f64()).collect()
    }
}
