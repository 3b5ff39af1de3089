//! Planar homographies between image and ground plane (paper Eq. 1: `p_world = H·p_image`).
//!
//! Points are homogeneous: `[u, v, 1]ᵀ` is mapped by the 3×3 matrix and divided by the third
//! component. What `(u, v)` means depends on the dataset: ETH `H.txt` expects `(row, col)`
//! pixel coordinates, UCY `H.txt` expects the `annotation.vsp` coordinates (pixels with the
//! origin at the image centre).

use crate::error::DataError;
use crate::text;
use nalgebra::Matrix3;
use std::path::Path;

/// Below this |w| a point maps to infinity (it lies on the horizon line of the homography).
const HORIZON_EPS: f64 = 1e-12;

/// A 3×3 planar homography from image coordinates to world metres, with its inverse.
#[derive(Clone, Debug, PartialEq)]
pub struct Homography {
    /// Image → world, row-major.
    pub h: [[f64; 3]; 3],
    /// World → image, row-major (`h⁻¹`).
    pub h_inv: [[f64; 3]; 3],
}

fn det3(m: &[[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// `m⁻¹`, or `None` when `m` is singular relative to its largest entry
/// (`|det| ≤ 1e-14·max|mᵢⱼ|³`) or its determinant is not finite.
fn inverse3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let det = det3(m);
    let scale = m.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if !det.is_finite() || det.abs() <= 1e-14 * scale.powi(3) {
        return None;
    }
    // nalgebra's closed-form 3×3 inverse: the adjugate divided by the same determinant.
    let inv = Matrix3::from_fn(|r, c| m[r][c]).try_inverse()?;
    Some(std::array::from_fn(|r| {
        std::array::from_fn(|c| inv[(r, c)])
    }))
}

fn apply(m: &[[f64; 3]; 3], p: [f64; 2]) -> Option<[f64; 2]> {
    let x = m[0][0] * p[0] + m[0][1] * p[1] + m[0][2];
    let y = m[1][0] * p[0] + m[1][1] * p[1] + m[1][2];
    let w = m[2][0] * p[0] + m[2][1] * p[1] + m[2][2];
    if w.abs() < HORIZON_EPS || !w.is_finite() {
        return None;
    }
    Some([x / w, y / w])
}

impl Homography {
    /// A homography from its image → world matrix; `None` when it is singular or not finite.
    pub fn new(h: [[f64; 3]; 3]) -> Option<Self> {
        if !h.iter().flatten().all(|v| v.is_finite()) {
            return None;
        }
        inverse3(&h).map(|h_inv| Self { h, h_inv })
    }

    /// The scale-only homography `world = s·(u, v)` (SDD: one meter-per-pixel scale per video).
    pub fn scale(s: f64) -> Option<Self> {
        Self::new([[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, 1.0]])
    }

    /// Reads a 3×3 matrix written as three whitespace-separated rows (`H.txt`).
    pub fn load(path: &Path) -> Result<Self, DataError> {
        let body = text::read(path)?;
        let mut rows = Vec::with_capacity(3);
        for (i, line) in body.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let toks = text::fields(line, 3, path, i + 1)?;
            if toks.len() != 3 {
                return Err(DataError::parse(
                    path,
                    i + 1,
                    format!("a homography row has 3 numbers, found {}", toks.len()),
                ));
            }
            let mut row = [0.0; 3];
            for (k, t) in toks.iter().enumerate() {
                row[k] = text::number(t, path, i + 1, &format!("H[{}][{k}]", rows.len()))?;
            }
            rows.push(row);
        }
        if rows.len() != 3 {
            return Err(DataError::parse(
                path,
                rows.len(),
                format!("a homography has 3 rows, found {}", rows.len()),
            ));
        }
        let h = [rows[0], rows[1], rows[2]];
        Self::new(h).ok_or_else(|| DataError::SingularHomography {
            path: path.to_path_buf(),
            det: det3(&h),
        })
    }

    /// Image → world (Eq. 1). `None` for a point on the homography's horizon.
    pub fn image_to_world(&self, p: [f64; 2]) -> Option<[f64; 2]> {
        apply(&self.h, p)
    }

    /// World → image. `None` for a point on the inverse's horizon.
    pub fn world_to_image(&self, p: [f64; 2]) -> Option<[f64; 2]> {
        apply(&self.h_inv, p)
    }

    /// The determinant of the image → world matrix.
    pub fn det(&self) -> f64 {
        det3(&self.h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    #[test]
    fn scale_homography_is_a_scale() {
        let h = Homography::scale(0.04).unwrap();
        let w = h.image_to_world([100.0, -50.0]).unwrap();
        assert_relative_eq!(w[0], 4.0, epsilon = 1e-12);
        assert_relative_eq!(w[1], -2.0, epsilon = 1e-12);
        assert!(Homography::scale(0.0).is_none());
    }

    #[test]
    fn singular_and_non_finite_matrices_are_rejected() {
        assert!(Homography::new([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]).is_none());
        assert!(
            Homography::new([[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_none()
        );
    }

    #[test]
    fn inverse_is_the_matrix_inverse() {
        let h = Homography::new([
            [0.0281, 0.0020, -4.669],
            [0.0008, 0.0252, -5.061],
            [0.00035, 0.0000925, 0.4626],
        ])
        .unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let v: f64 = (0..3).map(|k| h.h[i][k] * h.h_inv[k][j]).sum();
                assert_relative_eq!(v, if i == j { 1.0 } else { 0.0 }, epsilon = 1e-12);
            }
        }
    }

    /// The adjugate inverse this module computed by hand before it used nalgebra.
    fn adjugate_inverse(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
        let det = det3(m);
        let c = |r0: usize, r1: usize, c0: usize, c1: usize| {
            m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]
        };
        [
            [
                c(1, 2, 1, 2) / det,
                -c(0, 2, 1, 2) / det,
                c(0, 1, 1, 2) / det,
            ],
            [
                -c(1, 2, 0, 2) / det,
                c(0, 2, 0, 2) / det,
                -c(0, 1, 0, 2) / det,
            ],
            [
                c(1, 2, 0, 1) / det,
                -c(0, 2, 0, 1) / det,
                c(0, 1, 0, 1) / det,
            ],
        ]
    }

    #[test]
    fn inverse_equals_the_former_adjugate_inverse() {
        let mut cases = vec![
            [
                [0.0281, 0.0020, -4.669],
                [0.0008, 0.0252, -5.061],
                [0.00035, 0.0000925, 0.4626],
            ],
            [[0.04, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, 0.0, 1.0]],
            [[2.0, -1.0, 0.5], [1e-3, 3.0, -7.0], [1e-4, 2e-4, 1.0]],
        ];
        // Deterministic pseudo-random matrices over several orders of magnitude.
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for k in 0..500 {
            let mag = 10f64.powi(k % 7 - 3);
            cases.push(std::array::from_fn(|_| {
                std::array::from_fn(|_| next() * mag)
            }));
        }
        for m in &cases {
            let Some(inv) = inverse3(m) else {
                continue;
            };
            let old = adjugate_inverse(m);
            for (a, b) in inv.iter().flatten().zip(old.iter().flatten()) {
                // Equal as numbers (the sign of a zero entry may differ).
                assert_eq!(a, b, "{m:?}");
            }
        }
        assert!(inverse3(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]).is_none());
        assert!(inverse3(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-15]]).is_none());
        assert!(inverse3(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-13]]).is_some());
        assert!(inverse3(&[[1e300, 0.0, 0.0], [0.0, 1e300, 0.0], [0.0, 0.0, 1e300]]).is_none());
        assert!(inverse3(&[[0.0; 3]; 3]).is_none());
    }

    proptest! {
        #[test]
        fn perspective_round_trip(u in 0.0..640.0f64, v in 0.0..480.0f64) {
            let h = Homography::new([[0.0281, 0.0020, -4.669], [0.0008, 0.0252, -5.061], [0.00035, 0.0000925, 0.4626]]).unwrap();
            let w = h.image_to_world([u, v]).unwrap();
            let back = h.world_to_image(w).unwrap();
            prop_assert!((back[0] - u).abs() < 1e-8 && (back[1] - v).abs() < 1e-8);
        }
    }
}
