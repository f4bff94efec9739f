//! Relative pose from point correspondences: the 5-point essential-matrix solver
//! (Stewénius, Engels and Nistér, 2006: Gröbner basis via an action matrix) inside RANSAC,
//! and the decomposition of `E` into `(R, t)` with the cheirality check.
//!
//! Conventions: `x1`, `x2` are normalised image coordinates (`K^-1 [u v 1]^T`) of the same
//! point in camera 1 and camera 2, and `x2^T E x1 = 0` with `E = [t]x R`, where
//! `(R, t) = T_cam2_cam1` maps points from camera 1 into camera 2.

use crate::{Mat3, Vec3};
use nalgebra::{DMatrix, SMatrix};
use std::sync::OnceLock;

/// Monomials of degree <= 3 in (x, y, z), ordered as the elimination needs:
/// the ten cubics first, then the basis `x^2 xy xz y^2 yz z^2 x y z 1`.
const MONOMIALS: [(u8, u8, u8); 20] = [
    (3, 0, 0),
    (2, 1, 0),
    (2, 0, 1),
    (1, 2, 0),
    (1, 1, 1),
    (1, 0, 2),
    (0, 3, 0),
    (0, 2, 1),
    (0, 1, 2),
    (0, 0, 3),
    (2, 0, 0),
    (1, 1, 0),
    (1, 0, 1),
    (0, 2, 0),
    (0, 1, 1),
    (0, 0, 2),
    (1, 0, 0),
    (0, 1, 0),
    (0, 0, 1),
    (0, 0, 0),
];

/// `PRODUCT[i][j]`: index of monomial i * monomial j, or 255 past degree 3.
fn product_table() -> &'static [[u8; 20]; 20] {
    static T: OnceLock<[[u8; 20]; 20]> = OnceLock::new();
    T.get_or_init(|| {
        let mut t = [[255u8; 20]; 20];
        for (i, a) in MONOMIALS.iter().enumerate() {
            for (j, b) in MONOMIALS.iter().enumerate() {
                let m = (a.0 + b.0, a.1 + b.1, a.2 + b.2);
                if let Some(k) = MONOMIALS.iter().position(|&q| q == m) {
                    t[i][j] = k as u8;
                }
            }
        }
        t
    })
}

/// A polynomial of degree <= 3 in (x, y, z).
#[derive(Clone, Copy)]
struct Poly([f64; 20]);

impl Poly {
    fn zero() -> Self {
        Poly([0.0; 20])
    }
    fn linear(x: f64, y: f64, z: f64, w: f64) -> Self {
        let mut p = Self::zero();
        p.0[16] = x;
        p.0[17] = y;
        p.0[18] = z;
        p.0[19] = w;
        p
    }
    #[allow(clippy::needless_range_loop)] // index notation mirrors the algebra
    fn mul(&self, o: &Poly) -> Poly {
        let t = product_table();
        let mut r = Self::zero();
        for i in 0..20 {
            if self.0[i] == 0.0 {
                continue;
            }
            for j in 0..20 {
                if o.0[j] != 0.0 && t[i][j] != 255 {
                    r.0[t[i][j] as usize] += self.0[i] * o.0[j];
                }
            }
        }
        r
    }
    fn add(&self, o: &Poly) -> Poly {
        let mut r = *self;
        for i in 0..20 {
            r.0[i] += o.0[i];
        }
        r
    }
    fn scale(&self, s: f64) -> Poly {
        let mut r = *self;
        r.0.iter_mut().for_each(|v| *v *= s);
        r
    }
}

/// All essential matrices (up to 10) consistent with five correspondences.
#[allow(clippy::needless_range_loop)] // index notation mirrors the matrix algebra
pub fn five_point(x1: &[Vec3; 5], x2: &[Vec3; 5]) -> Vec<Mat3> {
    // null space of the 5x9 epipolar constraint matrix (padded to 9x9)
    let mut q = SMatrix::<f64, 9, 9>::zeros();
    for i in 0..5 {
        let (a, b) = (x1[i] / x1[i].z, x2[i] / x2[i].z);
        for r in 0..3 {
            for c in 0..3 {
                q[(i, 3 * r + c)] = b[r] * a[c];
            }
        }
    }
    if !q.iter().all(|v| v.is_finite()) {
        return Vec::new();
    }
    let Some(svd) = q.try_svd(false, true, f64::EPSILON, 10_000) else {
        return Vec::new();
    };
    let Some(vt) = svd.v_t else { return Vec::new() };
    // singular values are sorted descending: the last four rows span the null space
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
    let basis: Vec<[f64; 9]> = order[5..]
        .iter()
        .map(|&r| std::array::from_fn(|k| vt[(r, k)]))
        .collect();
    // E(x, y, z) = x X + y Y + z Z + W
    let e: [[Poly; 3]; 3] = std::array::from_fn(|r| {
        std::array::from_fn(|c| {
            let k = 3 * r + c;
            Poly::linear(basis[0][k], basis[1][k], basis[2][k], basis[3][k])
        })
    });
    let mut eqs: Vec<Poly> = Vec::with_capacity(10);
    // det(E) = 0
    let det = e[0][0]
        .mul(
            &e[1][1]
                .mul(&e[2][2])
                .add(&e[1][2].mul(&e[2][1]).scale(-1.0)),
        )
        .add(
            &e[0][1].mul(
                &e[1][2]
                    .mul(&e[2][0])
                    .add(&e[1][0].mul(&e[2][2]).scale(-1.0)),
            ),
        )
        .add(
            &e[0][2].mul(
                &e[1][0]
                    .mul(&e[2][1])
                    .add(&e[1][1].mul(&e[2][0]).scale(-1.0)),
            ),
        );
    eqs.push(det);
    // 2 E E^T E - tr(E E^T) E = 0
    let mut eet = [[Poly::zero(); 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            for k in 0..3 {
                eet[r][c] = eet[r][c].add(&e[r][k].mul(&e[c][k]));
            }
        }
    }
    let trace = eet[0][0].add(&eet[1][1]).add(&eet[2][2]);
    for r in 0..3 {
        for c in 0..3 {
            let mut acc = Poly::zero();
            for k in 0..3 {
                acc = acc.add(&eet[r][k].mul(&e[k][c]));
            }
            eqs.push(acc.scale(2.0).add(&trace.mul(&e[r][c]).scale(-1.0)));
        }
    }
    // Gauss-Jordan on the 10x20 coefficient matrix, partial pivoting
    let mut m = DMatrix::<f64>::from_fn(10, 20, |r, c| eqs[r].0[c]);
    for col in 0..10 {
        let (piv, best) = (col..10)
            .map(|r| (r, m[(r, col)].abs()))
            .fold((col, -1.0), |a, b| if b.1 > a.1 { b } else { a });
        if best < 1e-12 {
            return Vec::new();
        }
        m.swap_rows(col, piv);
        let p = m[(col, col)];
        for c in 0..20 {
            m[(col, c)] /= p;
        }
        for r in 0..10 {
            if r != col {
                let f = m[(r, col)];
                if f != 0.0 {
                    for c in 0..20 {
                        m[(r, c)] -= f * m[(col, c)];
                    }
                }
            }
        }
    }
    // action matrix of multiplication by x on the basis b = [x^2 xy xz y^2 yz z^2 x y z 1]
    let mut a = SMatrix::<f64, 10, 10>::zeros();
    for i in 0..6 {
        for j in 0..10 {
            a[(i, j)] = -m[(i, 10 + j)];
        }
    }
    a[(6, 0)] = 1.0; // x * x = x^2
    a[(7, 1)] = 1.0; // x * y = xy
    a[(8, 2)] = 1.0; // x * z = xz
    a[(9, 6)] = 1.0; // x * 1 = x
                     // nalgebra's plain eigen/SVD calls iterate without bound; a degenerate sample (e.g.
                     // repeated points) can give a matrix on which they never converge, so bound both and
                     // treat non-convergence as "no solution from this sample"
    let mut out = Vec::new();
    if !a.iter().all(|v| v.is_finite()) {
        return out;
    }
    let Some(schur) = nalgebra::linalg::Schur::try_new(a, f64::EPSILON, 10_000) else {
        return out;
    };
    for ev in schur.complex_eigenvalues().iter() {
        if ev.im.abs() > 1e-8 * (1.0 + ev.re.abs()) {
            continue;
        }
        let lambda = ev.re;
        let shifted = a - SMatrix::<f64, 10, 10>::identity() * lambda;
        let Some(s) = shifted.try_svd(false, true, f64::EPSILON, 10_000) else {
            continue;
        };
        let Some(vt) = s.v_t else { continue };
        let k = crate::argmin(s.singular_values.iter().copied());
        let v = vt.row(k);
        if v[9].abs() < 1e-12 {
            continue;
        }
        let (x, y, z) = (lambda, v[7] / v[9], v[8] / v[9]);
        let mut em = Mat3::zeros();
        for r in 0..3 {
            for c in 0..3 {
                let kk = 3 * r + c;
                em[(r, c)] = x * basis[0][kk] + y * basis[1][kk] + z * basis[2][kk] + basis[3][kk];
            }
        }
        let n = em.norm();
        if n > 0.0 && n.is_finite() {
            out.push(em / n);
        }
    }
    out
}

/// Squared Sampson distance of a correspondence to the epipolar geometry of `e`.
pub fn sampson_sq(e: &Mat3, x1: &Vec3, x2: &Vec3) -> f64 {
    let (a, b) = (x1 / x1.z, x2 / x2.z);
    let ex1 = e * a;
    let etx2 = e.transpose() * b;
    let num = b.dot(&ex1);
    let den = ex1.x * ex1.x + ex1.y * ex1.y + etx2.x * etx2.x + etx2.y * etx2.y;
    if den <= 0.0 {
        f64::INFINITY
    } else {
        num * num / den
    }
}

/// Settings of the essential-matrix RANSAC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RansacConfig {
    /// Inlier threshold in pixels (converted with the focal length).
    pub threshold_px: f64,
    /// Desired probability of drawing at least one all-inlier sample.
    pub confidence: f64,
    /// Upper bound on iterations.
    pub max_iterations: usize,
    /// Lower bound on iterations. The adaptive stopping rule assumes every all-inlier
    /// sample gives a good model; with pixel noise and forward motion the Sampson cost has
    /// several basins, so a floor on the sample count makes the good one likely.
    pub min_iterations: usize,
    /// Seed of the sampler (runs are deterministic for a seed).
    pub seed: u64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        Self {
            threshold_px: 1.0,
            confidence: 0.999,
            max_iterations: 1000,
            min_iterations: 200,
            seed: 0x5eed,
        }
    }
}

/// Result of [`find_essential`].
#[derive(Debug, Clone, PartialEq)]
pub struct EssentialEstimate {
    /// Essential matrix (unit Frobenius norm).
    pub e: Mat3,
    /// Inlier flag per correspondence.
    pub inliers: Vec<bool>,
    /// Iterations run.
    pub iterations: usize,
}

impl EssentialEstimate {
    /// Number of inliers.
    pub fn inlier_count(&self) -> usize {
        self.inliers.iter().filter(|&&b| b).count()
    }
}

/// Iterations for `confidence` of drawing at least one all-inlier sample of `sample` points
/// when a fraction `w` of the data are inliers, capped at `max`. No inliers yet means `max`.
pub(crate) fn ransac_iterations(w: f64, sample: i32, confidence: f64, max: usize) -> usize {
    let p = w.clamp(0.0, 1.0).powi(sample);
    if p <= f64::EPSILON {
        return max;
    }
    if p >= 1.0 - f64::EPSILON {
        return 1;
    }
    let n = (1.0 - confidence).ln() / (1.0 - p).ln();
    if n.is_finite() {
        (n.ceil() as usize).min(max)
    } else {
        max
    }
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// Essential matrix by 5-point RANSAC. `x1`, `x2`: normalised coordinates; `focal`: focal
/// length in pixels (for the pixel threshold). `None` with fewer than 5 correspondences or
/// when no sample gives a solution.
pub fn find_essential(
    x1: &[Vec3],
    x2: &[Vec3],
    focal: f64,
    cfg: &RansacConfig,
) -> Option<EssentialEstimate> {
    let n = x1.len().min(x2.len());
    if n < 5 || focal <= 0.0 {
        return None;
    }
    let thr_sq = (cfg.threshold_px / focal).powi(2);
    let mut rng = Rng(cfg.seed.max(1));
    // (model, inliers, MSAC score = sum of min(d^2, thr^2)); lower score wins
    let mut best: Option<(Mat3, usize, f64)> = None;
    let mut best_raw = f64::INFINITY;
    let mut needed = cfg.max_iterations;
    let mut it = 0;
    while it < needed.max(cfg.min_iterations).min(cfg.max_iterations) {
        it += 1;
        let mut idx = [0usize; 5];
        let mut k = 0;
        while k < 5 {
            let c = rng.below(n);
            if !idx[..k].contains(&c) {
                idx[k] = c;
                k += 1;
            }
        }
        let s1: [Vec3; 5] = std::array::from_fn(|i| x1[idx[i]]);
        let s2: [Vec3; 5] = std::array::from_fn(|i| x2[idx[i]]);
        for e in five_point(&s1, &s2) {
            let score = msac_score(&e, x1, x2, thr_sq);
            // LO-RANSAC: a hypothesis that beats the best *unpolished* score so far is
            // polished; the polished model then competes with the best polished one.
            if score < best_raw {
                best_raw = score;
                let (e, count, score) = local_optimisation(e, score, x1, x2, thr_sq);
                if best.as_ref().is_none_or(|b| score < b.2) {
                    best = Some((e, count, score));
                    needed = ransac_iterations(
                        count as f64 / n as f64,
                        5,
                        cfg.confidence,
                        cfg.max_iterations,
                    );
                }
            }
        }
    }
    let (e, _, _) = best?;
    let inliers = (0..n)
        .map(|i| sampson_sq(&e, &x1[i], &x2[i]) < thr_sq)
        .collect();
    Some(EssentialEstimate {
        e,
        inliers,
        iterations: it,
    })
}

/// Iterated local optimisation (LO-RANSAC, Chum et al. 2003): refine by minimising the
/// Sampson error over the points within a widened threshold (4x, then 2x, then 1x), so a
/// model from a noisy minimal sample can move out of the basin its own inlier set defines.
/// The result replaces the model only if its MSAC score is no worse.
fn local_optimisation(
    e: Mat3,
    score: f64,
    x1: &[Vec3],
    x2: &[Vec3],
    thr_sq: f64,
) -> (Mat3, usize, f64) {
    let n = x1.len().min(x2.len());
    let mut cur = e;
    for scale in [16.0, 4.0, 1.0, 1.0] {
        let inl: Vec<usize> = (0..n)
            .filter(|&i| sampson_sq(&cur, &x1[i], &x2[i]) < thr_sq * scale)
            .collect();
        let a: Vec<Vec3> = inl.iter().map(|&i| x1[i]).collect();
        let b: Vec<Vec3> = inl.iter().map(|&i| x2[i]).collect();
        cur = refine_essential(&cur, &a, &b, 15);
    }
    let s2 = msac_score(&cur, x1, x2, thr_sq);
    let (e, score) = if s2 <= score { (cur, s2) } else { (e, score) };
    let count = (0..n)
        .filter(|&i| sampson_sq(&e, &x1[i], &x2[i]) < thr_sq)
        .count();
    (e, count, score)
}

/// MSAC score: inliers cost their squared Sampson distance, outliers the squared threshold.
fn msac_score(e: &Mat3, x1: &[Vec3], x2: &[Vec3], thr_sq: f64) -> f64 {
    x1.iter()
        .zip(x2)
        .map(|(a, b)| sampson_sq(e, a, b).min(thr_sq))
        .sum()
}

/// Signed Sampson residual (normalised units).
fn sampson_residual(e: &Mat3, x1: &Vec3, x2: &Vec3) -> f64 {
    let (a, b) = (x1 / x1.z, x2 / x2.z);
    let ex1 = e * a;
    let etx2 = e.transpose() * b;
    let den = (ex1.x * ex1.x + ex1.y * ex1.y + etx2.x * etx2.x + etx2.y * etx2.y).sqrt();
    if den > 0.0 {
        b.dot(&ex1) / den
    } else {
        0.0
    }
}

/// The Sampson errors of correspondences under `E = [t]x R`, over the rotation (a right
/// perturbation) and the translation direction (on the unit sphere), with a
/// forward-difference Jacobian.
struct SampsonProblem<'a> {
    x1: &'a [Vec3],
    x2: &'a [Vec3],
}

impl SampsonProblem<'_> {
    fn essential((r, t): &(Mat3, Vec3)) -> Mat3 {
        crate::rotation::skew(t) * r
    }

    fn residuals(&self, e: &Mat3) -> impl Iterator<Item = f64> + '_ {
        let e = *e;
        self.x1
            .iter()
            .zip(self.x2)
            .map(move |(a, b)| sampson_residual(&e, a, b))
    }
}

impl supermvo_optim::LeastSquares for SampsonProblem<'_> {
    type State = (Mat3, Vec3);
    type System = (SMatrix<f64, 5, 5>, SMatrix<f64, 5, 1>);
    type Step = SMatrix<f64, 5, 1>;

    fn cost(&self, state: &(Mat3, Vec3)) -> f64 {
        self.residuals(&Self::essential(state))
            .map(|r| r.powi(2))
            .sum()
    }

    fn linearize(&mut self, state: &(Mat3, Vec3)) -> Option<Self::System> {
        let res: Vec<f64> = self.residuals(&Self::essential(state)).collect();
        let h = 1e-7;
        let cols: Vec<Vec<f64>> = (0..5)
            .map(|k| {
                let mut d = SMatrix::<f64, 5, 1>::zeros();
                d[k] = h;
                let moved = Self::essential(&self.retract(state, &d));
                self.residuals(&moved)
                    .zip(&res)
                    .map(|(rk, r0)| (rk - r0) / h)
                    .collect()
            })
            .collect();
        let mut jtj = SMatrix::<f64, 5, 5>::zeros();
        let mut jtr = SMatrix::<f64, 5, 1>::zeros();
        for (i, r) in res.iter().enumerate() {
            let j = SMatrix::<f64, 5, 1>::from_fn(|k, _| cols[k][i]);
            jtj += j * j.transpose();
            jtr += j * *r;
        }
        Some((jtj, jtr))
    }

    /// Damped by `lambda diag(H)`.
    fn solve(&mut self, (jtj, jtr): &Self::System, lambda: f64) -> Option<Self::Step> {
        let mut a = *jtj;
        for k in 0..5 {
            a[(k, k)] += lambda * (jtj[(k, k)] + 1e-12);
        }
        a.cholesky().map(|c| c.solve(&(-jtr)))
    }

    fn retract(&self, (r, t): &(Mat3, Vec3), d: &Self::Step) -> (Mat3, Vec3) {
        // tangent basis of the sphere at t
        let a = if t.x.abs() < 0.9 {
            Vec3::x()
        } else {
            Vec3::y()
        };
        let b1 = t.cross(&a).normalize();
        let b2 = t.cross(&b1);
        let r2 = r * crate::so3_exp(&Vec3::new(d[0], d[1], d[2]));
        let t2 = (t + b1 * d[3] + b2 * d[4]).normalize();
        (r2, t2)
    }
}

/// Levenberg-Marquardt on `E = [t]x R` (rotation by a right perturbation, `t` on the unit
/// sphere): minimises the sum of squared Sampson residuals of the given correspondences.
pub fn refine_essential(e: &Mat3, x1: &[Vec3], x2: &[Vec3], iterations: usize) -> Mat3 {
    let n = x1.len().min(x2.len());
    let svd = e.svd(true, true);
    let (Some(mut u), Some(mut vt)) = (svd.u, svd.v_t) else {
        return *e;
    };
    if n < 6 {
        return *e;
    }
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let w = Mat3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let start = (u * w * vt, u.column(2).into_owned());
    let mut problem = SampsonProblem {
        x1: &x1[..n],
        x2: &x2[..n],
    };
    let params = supermvo_optim::LmParams::marquardt(1e-3, 1e-9, 6, iterations);
    let refined = supermvo_optim::minimise(&mut problem, start, params).0;
    let em = SampsonProblem::essential(&refined);
    em / em.norm()
}

/// Linear (DLT) triangulation of one point seen by cameras `[I | 0]` and `[R | t]`;
/// returns the point in camera 1.
pub fn triangulate(r: &Mat3, t: &Vec3, x1: &Vec3, x2: &Vec3) -> Option<Vec3> {
    triangulate_views(&[(Mat3::identity(), Vec3::zeros(), *x1), (*r, *t, *x2)])
}

/// Linear (DLT) triangulation from any number of views, each `(R_cw, t_cw, bearing)` with
/// `p_cam = R_cw p + t_cw`; returns the point in the common (world) frame.
pub fn triangulate_views(views: &[(Mat3, Vec3, Vec3)]) -> Option<Vec3> {
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    for (r, t, b) in views {
        let (x, y) = (b.x / b.z, b.y / b.z);
        let row = |k: usize| nalgebra::RowVector4::new(r[(k, 0)], r[(k, 1)], r[(k, 2)], t[k]);
        for a in [row(2) * x - row(0), row(2) * y - row(1)] {
            ata += a.transpose() * a;
        }
    }
    let eig = ata.symmetric_eigen();
    let h = eig
        .eigenvectors
        .column(crate::argmin(eig.eigenvalues.iter().copied()));
    (h[3].abs() > 1e-12).then(|| Vec3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]))
}

/// A point from [`triangulate_checked`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Triangulated {
    /// The point in the common (world) frame.
    pub point: Vec3,
    /// Angle between the rays to it from the first and the last camera centre, degrees.
    pub parallax_deg: f64,
}

/// [`triangulate_views`], accepted only when the point lies in front of every view and
/// reprojects within `max_error` (normalised image units, pixels / focal) in each; with the
/// parallax between the first and the last view, for the caller's threshold.
pub fn triangulate_checked(views: &[(Mat3, Vec3, Vec3)], max_error: f64) -> Option<Triangulated> {
    let p = triangulate_views(views)?;
    let fits = views.iter().all(|(r, t, b)| {
        let q = r * p + t;
        let (u, v) = (b.x / b.z, b.y / b.z);
        q.z > 0.0 && ((q.x / q.z - u).powi(2) + (q.y / q.z - v).powi(2)).sqrt() < max_error
    });
    if !fits {
        return None;
    }
    let (first, last) = (views.first()?, views.last()?);
    let centre = |r: &Mat3, t: &Vec3| -(r.transpose() * t);
    let ray0 = (p - centre(&first.0, &first.1)).normalize();
    let ray1 = (p - centre(&last.0, &last.1)).normalize();
    Some(Triangulated {
        point: p,
        parallax_deg: ray0.dot(&ray1).clamp(-1.0, 1.0).acos().to_degrees(),
    })
}

/// Relative pose `T_cam2_cam1 = (R, t)` (with `|t| = 1`) from an essential matrix: of the
/// four decompositions, the one with most inliers triangulated in front of both cameras
/// (closer than `max_depth` baselines). Returns `(R, t, points in front)`.
pub fn recover_pose(
    e: &Mat3,
    x1: &[Vec3],
    x2: &[Vec3],
    inliers: &[bool],
    max_depth: f64,
) -> (Mat3, Vec3, usize) {
    let svd = e.svd(true, true);
    let (Some(mut u), Some(mut vt)) = (svd.u, svd.v_t) else {
        return (Mat3::identity(), Vec3::zeros(), 0);
    };
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let w = Mat3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let t = u.column(2).into_owned();
    let candidates = [
        (u * w * vt, t),
        (u * w * vt, -t),
        (u * w.transpose() * vt, t),
        (u * w.transpose() * vt, -t),
    ];
    let mut best = (Mat3::identity(), Vec3::zeros(), 0usize);
    for (r, t) in candidates {
        let good = (0..x1.len().min(x2.len()))
            .filter(|&i| inliers.get(i).copied().unwrap_or(false))
            .filter(|&i| match triangulate(&r, &t, &x1[i], &x2[i]) {
                Some(p) => {
                    let z2 = (r * p + t).z;
                    p.z > 0.0 && z2 > 0.0 && p.z < max_depth && z2 < max_depth
                }
                None => false,
            })
            .count();
        if good > best.2 {
            best = (r, t, good);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checked_triangulation_rejects_points_behind_or_off_their_rays() {
        let (r, t) = (Mat3::identity(), Vec3::new(-1.0, 0.0, 0.0));
        let p = Vec3::new(0.5, 0.2, 4.0);
        let view2 = |p: &Vec3| {
            let q = r * p + t;
            q / q.z
        };
        let good = [
            (Mat3::identity(), Vec3::zeros(), p / p.z),
            (r, t, view2(&p)),
        ];
        let tri = triangulate_checked(&good, 1e-6).unwrap();
        assert!((tri.point - p).norm() < 1e-9);
        // rays from (0,0,0) and (1,0,0) to p
        let expect = p
            .normalize()
            .dot(&(p - Vec3::new(1.0, 0.0, 0.0)).normalize())
            .acos()
            .to_degrees();
        assert!((tri.parallax_deg - expect).abs() < 1e-9);
        // a point behind both cameras (where the rays' backward extensions meet) is rejected
        let behind = -p;
        let bad = [
            (Mat3::identity(), Vec3::zeros(), behind / behind.z),
            (r, t, view2(&behind)),
        ];
        assert!(triangulate_checked(&bad, 1e-6).is_none());
        // an observation moved 10 px (focal 700) across the epipolar line (the baseline is
        // along x, so vertically) fails a 2 px threshold
        let mut off = good;
        off[1].2.y += 10.0 / 700.0;
        assert!(triangulate_checked(&off, 2.0 / 700.0).is_none());
    }

    #[test]
    fn degenerate_samples_return_promptly() {
        // repeated and collinear correspondences (duplicate keypoints do reach RANSAC):
        // no solution, or some, but no endless eigen-decomposition
        let p = Vec3::new(0.1, -0.2, 1.0);
        let same = [p; 5];
        let _ = five_point(&same, &same);
        let line: [Vec3; 5] = std::array::from_fn(|i| Vec3::new(0.1 * i as f64, 0.0, 1.0));
        let _ = five_point(&line, &line);
        let nan = [Vec3::new(f64::NAN, 0.0, 1.0); 5];
        assert!(five_point(&nan, &same).is_empty());
    }
    use crate::so3_exp;
    use proptest::prelude::*;

    fn scene(seed: u64, n: usize, r: &Mat3, t: &Vec3) -> (Vec<Vec3>, Vec<Vec3>) {
        let mut rng = Rng(seed | 1);
        let mut u = || (rng.next() >> 11) as f64 / (1u64 << 53) as f64;
        let mut x1 = Vec::new();
        let mut x2 = Vec::new();
        while x1.len() < n {
            let p = Vec3::new(u() * 8.0 - 4.0, u() * 4.0 - 2.0, 4.0 + u() * 20.0);
            let q = r * p + t;
            if q.z > 0.5 {
                x1.push(p / p.z);
                x2.push(q / q.z);
            }
        }
        (x1, x2)
    }

    #[test]
    fn iteration_count() {
        assert_eq!(
            ransac_iterations(0.0, 5, 0.999, 1000),
            1000,
            "no inliers yet: keep sampling"
        );
        assert_eq!(ransac_iterations(1.0, 5, 0.999, 1000), 1);
        // 50 % inliers, 5-point samples: log(0.001) / log(1 - 1/32) = 217.6
        assert_eq!(ransac_iterations(0.5, 5, 0.999, 1000), 218);
        assert_eq!(ransac_iterations(0.1, 5, 0.999, 1000), 1000);
    }

    #[test]
    fn exact_solution_is_among_the_roots() {
        let r = so3_exp(&Vec3::new(0.05, -0.2, 0.03));
        let t = Vec3::new(0.2, 0.05, -1.0).normalize();
        let (x1, x2) = scene(7, 5, &r, &t);
        let truth = crate::rotation::skew(&t) * r;
        let truth = truth / truth.norm();
        let sols = five_point(
            &std::array::from_fn(|i| x1[i]),
            &std::array::from_fn(|i| x2[i]),
        );
        assert!(!sols.is_empty());
        let best = sols
            .iter()
            .map(|e| (e - truth).norm().min((e + truth).norm()))
            .fold(f64::INFINITY, f64::min);
        assert!(best < 1e-6, "closest root is {best} away");
    }

    /// Noisy two-view problem: 200 points, +-0.5 px uniform noise, 30 % outliers (the first
    /// 60 correspondences). Runs RANSAC and checks it against the true model on the same data.
    fn check_case(seed: u64, yaw: f64, tx: f64) -> Result<(), String> {
        let r = so3_exp(&Vec3::new(0.01, yaw, -0.02));
        let t = Vec3::new(tx, 0.02, -1.0).normalize();
        let (mut x1, mut x2) = scene(seed, 200, &r, &t);
        let f = 700.0;
        let mut rng = Rng(seed * 31 + 7);
        let mut noise = || ((rng.next() >> 11) as f64 / (1u64 << 53) as f64 - 0.5) / f;
        for i in 0..200 {
            x1[i] += Vec3::new(noise(), noise(), 0.0);
            x2[i] += Vec3::new(noise(), noise(), 0.0);
        }
        for i in 0..60 {
            x2[i] = x2[(i * 7 + 13) % 200] + Vec3::new(0.05, -0.03, 0.0);
        }
        let est = find_essential(&x1, &x2, f, &RansacConfig::default()).ok_or("no estimate")?;
        // the true model's inliers at the same 1 px threshold, on the same noisy data
        let e_true = crate::rotation::skew(&t) * r;
        let thr_sq = (1.0 / f) * (1.0 / f);
        let truth = (0..200)
            .filter(|&i| sampson_sq(&e_true, &x1[i], &x2[i]) < thr_sq)
            .count();
        let (rr, tt, good) = recover_pose(&est.e, &x1, &x2, &est.inliers, 1e4);
        let msac = |e: &Mat3| {
            (0..200)
                .map(|i| sampson_sq(e, &x1[i], &x2[i]).min(thr_sq))
                .sum::<f64>()
                / thr_sq
        };
        if est.inlier_count() + 3 < truth {
            return Err(format!(
                "{} inliers, the true model has {truth}; rotation error {:.5} rad, t.dot {:.5}; MSAC score ours {:.2}, truth {:.2}",
                est.inlier_count(),
                crate::rotation_angle(&(rr.transpose() * r)),
                tt.dot(&t),
                msac(&est.e),
                msac(&e_true)
            ));
        }
        if (good as f64) < 0.9 * est.inlier_count() as f64 {
            return Err(format!("only {good} points in front"));
        }
        let rot_err = crate::rotation_angle(&(rr.transpose() * r));
        if rot_err >= 0.01 {
            return Err(format!("rotation error {rot_err}"));
        }
        if tt.dot(&t) <= 0.99 {
            return Err(format!("translation direction off: {tt} vs {t}"));
        }
        Ok(())
    }

    #[test]
    fn near_pure_forward_motion() {
        // found by the property test below with the old fixed inlier floor: the true model
        // itself has fewer than 130 inliers at 1 px on this noise draw
        check_case(433, -0.002303055021613858, 0.20235543015301014).unwrap();
    }

    proptest! {
        // deterministic for CI: a fixed seed, no regression files
        #![proptest_config(ProptestConfig {
            cases: 64,
            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed),
            failure_persistence: None,
            ..ProptestConfig::default()
        })]
        #[test]
        fn ransac_recovers_motion_with_noise_and_outliers(seed in 1u64..1000, yaw in -0.3f64..0.3, tx in -0.5f64..0.5) {
            let outcome = check_case(seed, yaw, tx);
            prop_assert!(outcome.is_ok(), "{:?}", outcome);
        }
    }
}
