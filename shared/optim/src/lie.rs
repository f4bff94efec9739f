//! SE(2), SE(3) and Sim(3) as Lie groups, with GTSAM's conventions so errors and steps match
//! it: tangent order `(x, y, theta)` for SE(2), `(omega, v)` for SE(3) and
//! `(omega, v, sigma)` for Sim(3) (`sigma` the log of the scale); retraction `X * Exp(delta)`;
//! `Local(a, b) = Log(a^-1 b)`.

use crate::so3::{skew, so3_exp, so3_log};
use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

/// A matrix Lie group with a `D`-dimensional tangent space.
pub trait LieGroup<const D: usize>: Copy + std::fmt::Debug {
    /// Identity element.
    fn identity() -> Self;
    /// `self * other`.
    fn compose(&self, other: &Self) -> Self;
    /// `self^-1`.
    fn inverse(&self) -> Self;
    /// Exponential map.
    fn exp(xi: &SVector<f64, D>) -> Self;
    /// Logarithm map.
    fn log(&self) -> SVector<f64, D>;
    /// Adjoint matrix: `self * Exp(xi) * self^-1 = Exp(Ad * xi)`.
    fn adjoint(&self) -> SMatrix<f64, D, D>;
    /// Lie bracket matrix `ad(xi)`.
    fn ad(xi: &SVector<f64, D>) -> SMatrix<f64, D, D>;

    /// `self^-1 * other`.
    fn between(&self, other: &Self) -> Self {
        self.inverse().compose(other)
    }
    /// `self * Exp(delta)`.
    fn retract(&self, delta: &SVector<f64, D>) -> Self {
        self.compose(&Self::exp(delta))
    }
    /// Inverse right Jacobian `J_r^-1(xi)`, with `Log(Exp(xi) Exp(d)) ~ xi + J_r^-1(xi) d`.
    fn right_jacobian_inverse(xi: &SVector<f64, D>) -> SMatrix<f64, D, D> {
        let jr = right_jacobian_series::<D>(&Self::ad(xi));
        jr.try_inverse().unwrap_or_else(SMatrix::identity)
    }
}

/// `J_r = sum_k (-ad)^k / (k + 1)!`, summed until the terms vanish (entire series).
pub fn right_jacobian_series<const D: usize>(ad: &SMatrix<f64, D, D>) -> SMatrix<f64, D, D> {
    let mut term = SMatrix::<f64, D, D>::identity();
    let mut sum = term;
    let minus = -ad;
    for k in 1..60 {
        term = term * minus / (k as f64 + 1.0);
        sum += term;
        if term.abs().max() < 1e-18 * (1.0 + sum.abs().max()) {
            break;
        }
    }
    sum
}

/// A planar rigid transform.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Se2 {
    /// Translation x.
    pub x: f64,
    /// Translation y.
    pub y: f64,
    /// Heading, radians.
    pub theta: f64,
}

impl Se2 {
    /// From components.
    pub fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }
}

/// `(sin w / w, (1 - cos w) / w)`, the coefficients of SE(2)'s `V` matrix, without the
/// cancellation of `1 - cos w` at small angles (it loses half the digits at `w ~ 1e-6`,
/// which is where finite differences and small optimiser steps evaluate it).
fn se2_v_coefficients(w: f64) -> (f64, f64) {
    if w.abs() < 1e-4 {
        let w2 = w * w;
        (1.0 - w2 / 6.0, w * (0.5 - w2 / 24.0))
    } else {
        let half = 0.5 * w;
        (w.sin() / w, 2.0 * half.sin() * half.sin() / w)
    }
}

fn wrap(a: f64) -> f64 {
    let r = a.sin().atan2(a.cos());
    if r == -std::f64::consts::PI {
        std::f64::consts::PI
    } else {
        r
    }
}

impl LieGroup<3> for Se2 {
    fn identity() -> Self {
        Se2::new(0.0, 0.0, 0.0)
    }
    fn compose(&self, o: &Self) -> Self {
        let (s, c) = self.theta.sin_cos();
        Se2::new(
            self.x + c * o.x - s * o.y,
            self.y + s * o.x + c * o.y,
            wrap(self.theta + o.theta),
        )
    }
    fn inverse(&self) -> Self {
        let (s, c) = self.theta.sin_cos();
        Se2::new(
            -(c * self.x + s * self.y),
            -(-s * self.x + c * self.y),
            wrap(-self.theta),
        )
    }
    fn exp(xi: &SVector<f64, 3>) -> Self {
        let (vx, vy, w) = (xi[0], xi[1], xi[2]);
        let (a, b) = se2_v_coefficients(w);
        Se2::new(a * vx - b * vy, b * vx + a * vy, wrap(w))
    }
    fn log(&self) -> SVector<f64, 3> {
        let w = self.theta;
        let (a, b) = se2_v_coefficients(w);
        let det = a * a + b * b;
        SVector::<f64, 3>::new(
            (a * self.x + b * self.y) / det,
            (-b * self.x + a * self.y) / det,
            w,
        )
    }
    fn adjoint(&self) -> SMatrix<f64, 3, 3> {
        let (s, c) = self.theta.sin_cos();
        SMatrix::<f64, 3, 3>::new(c, -s, self.y, s, c, -self.x, 0.0, 0.0, 1.0)
    }
    fn ad(xi: &SVector<f64, 3>) -> SMatrix<f64, 3, 3> {
        SMatrix::<f64, 3, 3>::new(0.0, -xi[2], xi[1], xi[2], 0.0, -xi[0], 0.0, 0.0, 0.0)
    }
}

/// A rigid transform in 3D: rotation matrix and translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Se3 {
    /// Rotation.
    pub r: Matrix3<f64>,
    /// Translation.
    pub t: Vector3<f64>,
}

impl Se3 {
    /// From a unit quaternion and translation.
    pub fn from_quaternion(q: &UnitQuaternion<f64>, t: Vector3<f64>) -> Self {
        Self {
            r: q.to_rotation_matrix().into_inner(),
            t,
        }
    }
}

/// `J_l(omega)` of SO(3) (maps tangent velocities to translation in Exp of SE(3)).
fn so3_left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let th = w.norm();
    let wx = skew(w);
    if th < 1e-8 {
        return Matrix3::identity() + 0.5 * wx + wx * wx / 6.0;
    }
    let th2 = th * th;
    Matrix3::identity() + (1.0 - th.cos()) / th2 * wx + (th - th.sin()) / (th2 * th) * wx * wx
}

/// `J_l(omega)^-1` of SO(3).
fn so3_left_jacobian_inverse(w: &Vector3<f64>) -> Matrix3<f64> {
    let th = w.norm();
    let wx = skew(w);
    if th < 1e-8 {
        return Matrix3::identity() - 0.5 * wx + wx * wx / 12.0;
    }
    let half = 0.5 * th;
    let coef = (1.0 - half * half.cos() / half.sin()) / (th * th);
    Matrix3::identity() - 0.5 * wx + coef * wx * wx
}

impl LieGroup<6> for Se3 {
    fn identity() -> Self {
        Se3 {
            r: Matrix3::identity(),
            t: Vector3::zeros(),
        }
    }
    fn compose(&self, o: &Self) -> Self {
        Se3 {
            r: self.r * o.r,
            t: self.r * o.t + self.t,
        }
    }
    fn inverse(&self) -> Self {
        let rt = self.r.transpose();
        Se3 {
            r: rt,
            t: -(rt * self.t),
        }
    }
    fn exp(xi: &SVector<f64, 6>) -> Self {
        let w = Vector3::new(xi[0], xi[1], xi[2]);
        let v = Vector3::new(xi[3], xi[4], xi[5]);
        Se3 {
            r: so3_exp(&w),
            t: so3_left_jacobian(&w) * v,
        }
    }
    fn log(&self) -> SVector<f64, 6> {
        let w = so3_log(&self.r);
        let v = so3_left_jacobian_inverse(&w) * self.t;
        SVector::<f64, 6>::new(w.x, w.y, w.z, v.x, v.y, v.z)
    }
    fn adjoint(&self) -> SMatrix<f64, 6, 6> {
        let mut a = SMatrix::<f64, 6, 6>::zeros();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.r);
        a.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.r);
        a.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(skew(&self.t) * self.r));
        a
    }
    /// Closed form: `J_r^-1 = [[A, 0], [-A Q_r A, A]]` with `A = J_r^-1(omega)` of SO(3)
    /// and `Q_r(omega, v) = Q_l(-omega, -v)` (Barfoot, State Estimation for Robotics, 7.86);
    /// near zero rotation the series is used.
    fn right_jacobian_inverse(xi: &SVector<f64, 6>) -> SMatrix<f64, 6, 6> {
        let w = Vector3::new(xi[0], xi[1], xi[2]);
        let th = w.norm();
        if th < 1e-2 {
            let jr = right_jacobian_series::<6>(&Self::ad(xi));
            return jr.try_inverse().unwrap_or_else(SMatrix::identity);
        }
        let (p, r) = (skew(&(-w)), skew(&(-Vector3::new(xi[3], xi[4], xi[5]))));
        let (st, ct) = th.sin_cos();
        let (t2, t3) = (th * th, th * th * th);
        let (t4, t5) = (t3 * th, t3 * t2);
        let prp = p * r * p;
        let q = 0.5 * r
            + (th - st) / t3 * (p * r + r * p + prp)
            + (t2 + 2.0 * ct - 2.0) / (2.0 * t4) * (p * p * r + r * p * p - 3.0 * prp)
            + (2.0 * th - 3.0 * st + th * ct) / (2.0 * t5) * (prp * p + p * prp);
        let wx = skew(&w);
        let a =
            Matrix3::identity() + 0.5 * wx + (1.0 / t2 - (1.0 + ct) / (2.0 * th * st)) * wx * wx;
        let mut j = SMatrix::<f64, 6, 6>::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&a);
        j.fixed_view_mut::<3, 3>(3, 3).copy_from(&a);
        j.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-(a * q * a)));
        j
    }
    fn ad(xi: &SVector<f64, 6>) -> SMatrix<f64, 6, 6> {
        let wx = skew(&Vector3::new(xi[0], xi[1], xi[2]));
        let vx = skew(&Vector3::new(xi[3], xi[4], xi[5]));
        let mut a = SMatrix::<f64, 6, 6>::zeros();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&wx);
        a.fixed_view_mut::<3, 3>(3, 3).copy_from(&wx);
        a.fixed_view_mut::<3, 3>(3, 0).copy_from(&vx);
        a
    }
}

/// A similarity transform `x -> s R x + t` as a Lie group (for pose graphs whose keyframes
/// may disagree in scale, as monocular odometry's do).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    /// Rotation.
    pub r: Matrix3<f64>,
    /// Translation.
    pub t: Vector3<f64>,
    /// Scale, positive.
    pub s: f64,
}

impl Sim3 {
    /// The same similarity with its rotation projected back onto SO(3) (see
    /// [`crate::so3::nearest_rotation`]).
    pub fn with_nearest_rotation(&self) -> Self {
        Self {
            r: crate::so3::nearest_rotation(&self.r),
            ..*self
        }
    }

    /// A rigid transform (scale 1).
    pub fn from_se3(x: &Se3) -> Self {
        Self {
            r: x.r,
            t: x.t,
            s: 1.0,
        }
    }

    /// Applies the transform to a point.
    pub fn transform(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.s * (self.r * p) + self.t
    }
}

/// `W(omega, sigma) = sum_k A^k / (k + 1)!` with `A = [omega]x + sigma I`: the matrix that maps
/// the tangent translation to the translation of `Exp` (the series is entire, so it converges
/// for every argument; terms are summed until they vanish).
fn sim3_w(w: &Vector3<f64>, sigma: f64) -> Matrix3<f64> {
    let a = skew(w) + Matrix3::identity() * sigma;
    let mut term = Matrix3::identity();
    let mut sum = term;
    for k in 1..80 {
        term = term * a / (k as f64 + 1.0);
        sum += term;
        if term.abs().max() < 1e-17 * (1.0 + sum.abs().max()) {
            break;
        }
    }
    sum
}

impl LieGroup<7> for Sim3 {
    fn identity() -> Self {
        Sim3 {
            r: Matrix3::identity(),
            t: Vector3::zeros(),
            s: 1.0,
        }
    }
    fn compose(&self, o: &Self) -> Self {
        Sim3 {
            r: self.r * o.r,
            t: self.s * (self.r * o.t) + self.t,
            s: self.s * o.s,
        }
    }
    fn inverse(&self) -> Self {
        let rt = self.r.transpose();
        Sim3 {
            r: rt,
            t: -(rt * self.t) / self.s,
            s: 1.0 / self.s,
        }
    }
    fn exp(xi: &SVector<f64, 7>) -> Self {
        let w = Vector3::new(xi[0], xi[1], xi[2]);
        let v = Vector3::new(xi[3], xi[4], xi[5]);
        Sim3 {
            r: so3_exp(&w),
            t: sim3_w(&w, xi[6]) * v,
            s: xi[6].exp(),
        }
    }
    fn log(&self) -> SVector<f64, 7> {
        let w = so3_log(&self.r);
        let sigma = self.s.ln();
        let v = sim3_w(&w, sigma)
            .try_inverse()
            .map_or(self.t, |wi| wi * self.t);
        SVector::<f64, 7>::from_column_slice(&[w.x, w.y, w.z, v.x, v.y, v.z, sigma])
    }
    /// `Ad = [[R, 0, 0], [[t]x R, s R, -t], [0, 0, 1]]`.
    fn adjoint(&self) -> SMatrix<f64, 7, 7> {
        let mut a = SMatrix::<f64, 7, 7>::zeros();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.r);
        a.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(skew(&self.t) * self.r));
        a.fixed_view_mut::<3, 3>(3, 3).copy_from(&(self.r * self.s));
        a.fixed_view_mut::<3, 1>(3, 6).copy_from(&(-self.t));
        a[(6, 6)] = 1.0;
        a
    }
    /// `ad(xi) = [[[w]x, 0, 0], [[v]x, [w]x + sigma I, -v], [0, 0, 0]]`.
    fn ad(xi: &SVector<f64, 7>) -> SMatrix<f64, 7, 7> {
        let v = Vector3::new(xi[3], xi[4], xi[5]);
        let wx = skew(&Vector3::new(xi[0], xi[1], xi[2]));
        let mut a = SMatrix::<f64, 7, 7>::zeros();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&wx);
        a.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew(&v));
        a.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(wx + Matrix3::identity() * xi[6]));
        a.fixed_view_mut::<3, 1>(3, 6).copy_from(&(-v));
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn numeric_jr_inv<G: LieGroup<D>, const D: usize>(xi: &SVector<f64, D>) -> SMatrix<f64, D, D> {
        let x = G::exp(xi);
        let h = 1e-6;
        let mut j = SMatrix::<f64, D, D>::zeros();
        for k in 0..D {
            let mut d = SVector::<f64, D>::zeros();
            d[k] = h;
            let plus = x.retract(&d).log();
            d[k] = -h;
            let minus = x.retract(&d).log();
            j.set_column(k, &((plus - minus) / (2.0 * h)));
        }
        j
    }

    proptest! {
        #[test]
        fn se3_group_laws(a in proptest::array::uniform6(-1.5f64..1.5), b in proptest::array::uniform6(-1.5f64..1.5)) {
            let (xa, xb) = (SVector::<f64, 6>::from(a), SVector::<f64, 6>::from(b));
            let (pa, pb) = (Se3::exp(&xa), Se3::exp(&xb));
            prop_assert!((pa.log() - xa).norm() < 1e-9, "log(exp(x)) = x");
            let id = pa.compose(&pa.inverse());
            prop_assert!(id.log().norm() < 1e-12, "x x^-1 = 1");
            // adjoint: a Exp(x) a^-1 = Exp(Ad_a x)
            let lhs = pa.compose(&Se3::exp(&xb)).compose(&pa.inverse());
            let rhs = Se3::exp(&(pa.adjoint() * xb));
            prop_assert!(lhs.between(&rhs).log().norm() < 1e-9);
            // associativity
            let c = Se3::exp(&(xa * 0.3));
            let l = pa.compose(&pb).compose(&c);
            let r = pa.compose(&pb.compose(&c));
            prop_assert!(l.between(&r).log().norm() < 1e-12);
            // inverse right Jacobian against finite differences
            let jn = numeric_jr_inv::<Se3, 6>(&xa);
            let closed = Se3::right_jacobian_inverse(&xa);
            prop_assert!((closed - jn).abs().max() < 1e-6, "closed form vs finite differences");
            let series = right_jacobian_series::<6>(&Se3::ad(&xa)).try_inverse().unwrap();
            prop_assert!((closed - series).abs().max() < 1e-9, "closed form vs series");
        }

        #[test]
        fn sim3_group_laws(a in proptest::array::uniform7(-1.5f64..1.5), b in proptest::array::uniform7(-1.5f64..1.5)) {
            let (xa, xb) = (SVector::<f64, 7>::from(a), SVector::<f64, 7>::from(b));
            let (pa, pb) = (Sim3::exp(&xa), Sim3::exp(&xb));
            prop_assert!((pa.log() - xa).norm() < 1e-9, "log(exp(x)) = x");
            prop_assert!(pa.compose(&pa.inverse()).log().norm() < 1e-12, "x x^-1 = 1");
            let lhs = pa.compose(&pb).compose(&pa.inverse());
            let rhs = Sim3::exp(&(pa.adjoint() * xb));
            prop_assert!(lhs.between(&rhs).log().norm() < 1e-9, "adjoint");
            // Exp agrees with the matrix exponential of the 4x4 generator.
            let mut g = nalgebra::Matrix4::<f64>::zeros();
            g.fixed_view_mut::<3, 3>(0, 0).copy_from(&(skew(&Vector3::new(a[0], a[1], a[2])) + Matrix3::identity() * a[6]));
            g.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::new(a[3], a[4], a[5]));
            let m = g.exp();
            let sr = pa.r * pa.s;
            prop_assert!((m.fixed_view::<3, 3>(0, 0) - sr).abs().max() < 1e-9);
            prop_assert!((m.fixed_view::<3, 1>(0, 3) - pa.t).abs().max() < 1e-9);
            // The bracket: ad(a) b = [a^, b^].
            let gen = |x: &SVector<f64, 7>| {
                let mut g = nalgebra::Matrix4::<f64>::zeros();
                g.fixed_view_mut::<3, 3>(0, 0).copy_from(&(skew(&Vector3::new(x[0], x[1], x[2])) + Matrix3::identity() * x[6]));
                g.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::new(x[3], x[4], x[5]));
                g
            };
            let br = gen(&xa) * gen(&xb) - gen(&xb) * gen(&xa);
            prop_assert!((gen(&(Sim3::ad(&xa) * xb)) - br).abs().max() < 1e-12);
            let jn = numeric_jr_inv::<Sim3, 7>(&xa);
            prop_assert!((Sim3::right_jacobian_inverse(&xa) - jn).abs().max() < 1e-6);
        }

        #[test]
        fn se2_group_laws(a in proptest::array::uniform3(-3.0f64..3.0), b in proptest::array::uniform3(-3.0f64..3.0)) {
            let (xa, xb) = (SVector::<f64, 3>::from(a), SVector::<f64, 3>::from(b));
            let pa = Se2::exp(&xa);
            prop_assert!((pa.log() - xa).norm() < 1e-9);
            prop_assert!(pa.compose(&pa.inverse()).log().norm() < 1e-12);
            let lhs = pa.compose(&Se2::exp(&xb)).compose(&pa.inverse());
            let rhs = Se2::exp(&(pa.adjoint() * xb));
            prop_assert!(lhs.between(&rhs).log().norm() < 1e-9);
            let jn = numeric_jr_inv::<Se2, 3>(&xa);
            prop_assert!((Se2::right_jacobian_inverse(&xa) - jn).abs().max() < 1e-6);
        }
    }
}
