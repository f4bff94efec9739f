//! SO(3) as the optimisers use it: exponential and logarithm maps, the skew matrix, and the
//! quaternion of a rotation matrix (the basis of a logarithm that keeps full precision for
//! small angles).

use nalgebra::{Matrix3, Quaternion, Rotation3, Vector3};

/// Quaternion of a (nearly) orthonormal matrix by the numerically stable branch choice
/// (largest of the trace and the diagonal), normalised, with non-negative scalar part.
pub fn quaternion_of(r: &Matrix3<f64>) -> Quaternion<f64> {
    let tr = r.trace();
    let d = [r[(0, 0)], r[(1, 1)], r[(2, 2)]];
    let (mut best, mut best_val) = (3usize, tr);
    for (i, v) in d.iter().enumerate() {
        if *v > best_val {
            best = i;
            best_val = *v;
        }
    }
    // q = [x, y, z, w]
    let mut q = [0.0_f64; 4];
    if best == 3 {
        q[0] = r[(2, 1)] - r[(1, 2)];
        q[1] = r[(0, 2)] - r[(2, 0)];
        q[2] = r[(1, 0)] - r[(0, 1)];
        q[3] = 1.0 + tr;
    } else {
        let i = best;
        let j = (i + 1) % 3;
        let k = (j + 1) % 3;
        q[i] = 1.0 - tr + 2.0 * r[(i, i)];
        q[j] = r[(j, i)] + r[(i, j)];
        q[k] = r[(k, i)] + r[(i, k)];
        q[3] = r[(k, j)] - r[(j, k)];
    }
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let s = if q[3] < 0.0 { -1.0 / n } else { 1.0 / n };
    Quaternion::new(q[3] * s, q[0] * s, q[1] * s, q[2] * s)
}

/// Rotation vector (axis * angle, radians) of a rotation matrix: the SO(3) logarithm.
///
/// Computed through the quaternion, which keeps full relative precision for small
/// angles where `acos((tr R - 1) / 2)` loses half the digits.
pub fn so3_log(r: &Matrix3<f64>) -> Vector3<f64> {
    let q = quaternion_of(r);
    let v = q.imag();
    let vn = v.norm();
    let angle = 2.0 * vn.atan2(q.w);
    if angle <= 1e-3 {
        // Taylor expansion of angle / sin(angle / 2).
        let a2 = angle * angle;
        let scale = 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0;
        v * scale
    } else {
        v * (angle / (angle / 2.0).sin())
    }
}

/// SO(3) exponential: rotation matrix of a rotation vector.
pub fn so3_exp(w: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::new(*w).into_inner()
}

/// The rotation nearest to `m` (Frobenius norm): the orthonormal polar factor, through the
/// SVD, with the sign that keeps the determinant +1. A product of many rotations drifts off
/// SO(3) by rounding; where poses go round a loop (the tracker applying the loop closer's
/// corrections and reporting poses it then corrects again) that error grows with every
/// pass unless each pass starts from a rotation again.
pub fn nearest_rotation(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return *m;
    };
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    u * d * v_t
}

/// Skew-symmetric matrix `[v]x` with `[v]x w = v x w`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rotation stays itself; a matrix a little off SO(3) comes back a rotation next to it.
    #[test]
    fn nearest_rotation_projects_onto_so3() {
        let r = so3_exp(&Vector3::new(0.3, -1.2, 0.7));
        assert!((nearest_rotation(&r) - r).abs().max() < 1e-14);
        let skewed = r * Matrix3::new(1.0, 3e-4, 0.0, -1e-4, 1.0002, 2e-4, 0.0, 0.0, 0.9999);
        let p = nearest_rotation(&skewed);
        assert!((p.transpose() * p - Matrix3::identity()).abs().max() < 1e-14);
        assert!((p.determinant() - 1.0).abs() < 1e-14);
        assert!((p - r).abs().max() < 5e-4, "{}", (p - r).abs().max());
    }
}
