//! Loop closure: place recognition over keyframes, geometric verification with a Sim(3)
//! between the two places' triangulated points, and a Sim(3) pose graph of keyframes that
//! spreads the drift (scale included) along the loop.
//!
//! Place recognition aggregates each keyframe's learned descriptors into a VLAD vector over
//! a small vocabulary that is learned at the start of the run from the first keyframes'
//! descriptors (k-means, fixed seed): no training data is shipped or needed, the vocabulary
//! fits the camera and scene at hand, and VLAD's residual aggregation keeps far more of the
//! descriptor than a bag of words of the same size. A candidate is accepted only when the
//! two keyframes' 3D points agree under one similarity (RANSAC, reprojection in both images)
//! and the next keyframe finds the same place again.
//!
//! Frames: keyframe poses are `T_world_cam`; a keyframe's points are in its own camera frame
//! at the map scale of the moment, so the verified transform carries the scale drift between
//! the two visits.

use nalgebra::{DMatrix, SVector};
use supermvo_dataset::Calibration;
use supermvo_geometry::essential::triangulate_checked;
use supermvo_geometry::{umeyama, Mat3, Pose, Vec3};
use supermvo_inference::Features;
use supermvo_optim::lie::{LieGroup, Sim3};
use supermvo_optim::{Between, Kernel, Lm, LmParams, PoseGraph, Prior};

/// Loop-closure settings.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopConfig {
    /// Words of the VLAD vocabulary.
    pub vocabulary_size: usize,
    /// Keyframes whose descriptors train the vocabulary.
    pub vocabulary_keyframes: usize,
    /// Keyframes that must separate a query from a candidate (recent places are not loops).
    pub min_separation: usize,
    /// Best-scoring candidates verified per keyframe.
    pub candidates: usize,
    /// Minimum cosine similarity of mutually nearest descriptors.
    pub min_cosine: f32,
    /// 3D-3D inliers a loop needs.
    pub min_inliers: usize,
    /// Reprojection threshold of the verification, pixels.
    pub reprojection_px: f64,
    /// Consecutive keyframes that must see the same place before a loop is accepted.
    pub consistency: usize,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            vocabulary_size: 32,
            vocabulary_keyframes: 10,
            min_separation: 40,
            candidates: 3,
            min_cosine: 0.8,
            min_inliers: 20,
            reprojection_px: 3.0,
            consistency: 2,
        }
    }
}

/// An accepted loop.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LoopEdge {
    /// Frame index of the keyframe that recognised the place.
    pub query_frame: usize,
    /// Frame index of the earlier keyframe it recognised.
    pub match_frame: usize,
    /// Verified 3D-3D inliers.
    pub inliers: usize,
    /// Scale of the query's map relative to the match's (1 without drift).
    pub scale: f64,
    /// VLAD similarity.
    pub similarity: f32,
}

/// A correction of the world frame after a loop: the similarity that takes everything the
/// tracker estimated (its map and poses) to the corrected world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correction {
    /// Frame index of the keyframe at which the loop was closed.
    pub frame: usize,
    /// `x_corrected = s R x + t`.
    pub sim3: Sim3,
}

struct KeyframeEntry {
    frame: usize,
    /// Pose in the odometry frame (the tracker's frame with all corrections undone).
    odom: Sim3,
    /// Current best estimate.
    opt: Sim3,
    keypoints: Vec<[f32; 2]>,
    /// Unit descriptors, one row per keypoint.
    desc: DMatrix<f32>,
    /// Triangulated point of each keypoint, in this keyframe's camera frame.
    points: Vec<Option<Vec3>>,
    vlad: Option<Vec<f32>>,
}

/// A recognised but not yet confirmed place.
#[derive(Debug, Clone, Copy)]
struct Detection {
    keyframe: usize,
    matched: usize,
    rel: Sim3,
    inliers: usize,
    similarity: f32,
}

/// The loop closer (see module docs).
pub struct LoopCloser {
    calib: Calibration,
    cfg: LoopConfig,
    keyframes: Vec<KeyframeEntry>,
    vocabulary: Option<DMatrix<f32>>,
    loops: Vec<(usize, usize, Sim3, LoopEdge)>,
    pending: Vec<Detection>,
    /// Correction the tracker has applied: tracker frame = `fix` * odometry frame.
    fix: Sim3,
    /// Every estimated frame: (frame, pose in the odometry frame, keyframe entry index, pose
    /// as reported).
    frames: Vec<(usize, Sim3, usize, Pose)>,
    disabled: Option<String>,
}

impl std::fmt::Debug for LoopCloser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "LoopCloser({} keyframes, {} loops)",
            self.keyframes.len(),
            self.loops.len()
        )
    }
}

fn sim3_of(p: &Pose) -> Sim3 {
    Sim3 {
        r: p.r,
        t: p.t,
        s: 1.0,
    }
}

/// The rigid camera pose `T_world_cam` of a similarity world<-camera (the scale only
/// changes positions).
pub fn pose_of(s: &Sim3) -> Pose {
    Pose::new(s.r, s.t)
}

/// Mutually nearest neighbours between two sets of unit descriptors (rows) with cosine
/// similarity at least `min_cos`.
fn mutual_matches(a: &DMatrix<f32>, b: &DMatrix<f32>, min_cos: f32) -> Vec<(usize, usize)> {
    if a.nrows() == 0 || b.nrows() == 0 {
        return Vec::new();
    }
    let sim = a * b.transpose();
    let best_b: Vec<(usize, f32)> =
        (0..sim.nrows())
            .map(|i| {
                let row = sim.row(i);
                let (j, v) = row.iter().enumerate().fold((0, f32::MIN), |acc, (j, &v)| {
                    if v > acc.1 {
                        (j, v)
                    } else {
                        acc
                    }
                });
                (j, v)
            })
            .collect();
    let best_a: Vec<usize> = (0..sim.ncols())
        .map(|j| {
            sim.column(j)
                .iter()
                .enumerate()
                .fold(
                    (0, f32::MIN),
                    |acc, (i, &v)| if v > acc.1 { (i, v) } else { acc },
                )
                .0
        })
        .collect();
    best_b
        .iter()
        .enumerate()
        .filter(|(i, (j, v))| *v >= min_cos && best_a[*j] == *i)
        .map(|(i, (j, _))| (i, *j))
        .collect()
}

/// Deterministic k-means (k-means++ seeding from a fixed-seed generator, Lloyd iterations)
/// on unit descriptors; returns unit centres as rows.
fn kmeans(data: &DMatrix<f32>, k: usize, iterations: usize) -> DMatrix<f32> {
    let (n, d) = (data.nrows(), data.ncols());
    let k = k.min(n).max(1);
    let mut rng = supermvo_geometry::rng::SplitMix64::new(0x5EED);
    let mut next = || rng.next_f64();
    let mut centres = DMatrix::<f32>::zeros(k, d);
    centres
        .row_mut(0)
        .copy_from(&data.row((next() * n as f64) as usize % n));
    let mut dist = vec![f32::MAX; n];
    for c in 1..k {
        for (i, di) in dist.iter_mut().enumerate() {
            let e = (data.row(i) - centres.row(c - 1)).norm_squared();
            *di = di.min(e);
        }
        let total: f64 = dist.iter().map(|&v| v as f64).sum();
        let mut target = next() * total;
        let mut pick = n - 1;
        for (i, &v) in dist.iter().enumerate() {
            target -= v as f64;
            if target <= 0.0 {
                pick = i;
                break;
            }
        }
        centres.row_mut(c).copy_from(&data.row(pick));
    }
    for _ in 0..iterations {
        let assign = nearest_rows(data, &centres);
        let mut sums = DMatrix::<f32>::zeros(k, d);
        for (i, &c) in assign.iter().enumerate() {
            let row = sums.row(c) + data.row(i);
            sums.row_mut(c).copy_from(&row);
        }
        for c in 0..k {
            let norm = sums.row(c).norm();
            if norm > 0.0 {
                let row = sums.row(c) / norm;
                centres.row_mut(c).copy_from(&row);
            }
        }
    }
    centres
}

fn nearest_rows(data: &DMatrix<f32>, centres: &DMatrix<f32>) -> Vec<usize> {
    let sim = data * centres.transpose();
    (0..sim.nrows())
        .map(|i| {
            sim.row(i)
                .iter()
                .enumerate()
                .fold(
                    (0, f32::MIN),
                    |acc, (j, &v)| if v > acc.1 { (j, v) } else { acc },
                )
                .0
        })
        .collect()
}

/// VLAD: per word, the sum of residuals of the descriptors assigned to it; each word's block
/// normalised (intra-normalisation), then the whole vector.
fn vlad(desc: &DMatrix<f32>, vocabulary: &DMatrix<f32>) -> Vec<f32> {
    let (k, d) = (vocabulary.nrows(), vocabulary.ncols());
    let mut v = vec![0.0f32; k * d];
    for (i, &c) in nearest_rows(desc, vocabulary).iter().enumerate() {
        for j in 0..d {
            v[c * d + j] += desc[(i, j)] - vocabulary[(c, j)];
        }
    }
    for block in v.chunks_mut(d) {
        let n = block.iter().map(|x| x * x).sum::<f32>().sqrt();
        if n > 0.0 {
            block.iter_mut().for_each(|x| *x /= n);
        }
    }
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 {
        v.iter_mut().for_each(|x| *x /= n);
    }
    v
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl LoopCloser {
    /// A loop closer for a camera with calibration `calib`.
    pub fn new(calib: Calibration, cfg: LoopConfig) -> Self {
        Self {
            calib,
            cfg,
            keyframes: Vec::new(),
            vocabulary: None,
            loops: Vec::new(),
            pending: Vec::new(),
            fix: Sim3::identity(),
            frames: Vec::new(),
            disabled: None,
        }
    }

    /// Accepted loops so far.
    pub fn loops(&self) -> Vec<LoopEdge> {
        self.loops.iter().map(|l| l.3.clone()).collect()
    }

    /// Why loop closure is off for this run (features without float descriptors), if it is.
    pub fn disabled_reason(&self) -> Option<&str> {
        self.disabled.as_deref()
    }

    fn project(&self, p: &Vec3) -> Option<(f64, f64)> {
        (p.z > 1e-6).then(|| {
            (
                self.calib.fx * p.x / p.z + self.calib.cx,
                self.calib.fy * p.y / p.z + self.calib.cy,
            )
        })
    }

    fn bearing(&self, kp: &[f32; 2]) -> Vec3 {
        Vec3::new(
            (kp[0] as f64 - self.calib.cx) / self.calib.fx,
            (kp[1] as f64 - self.calib.cy) / self.calib.fy,
            1.0,
        )
    }

    /// Records a tracked non-keyframe (its pose as the tracker reported it), so that the
    /// corrected trajectory covers every frame.
    pub fn add_frame(&mut self, frame: usize, t_world_cam: &Pose) {
        if let Some(k) = self.keyframes.len().checked_sub(1) {
            let odom = self.fix.inverse().compose(&sim3_of(t_world_cam));
            self.frames.push((frame, odom, k, *t_world_cam));
        }
    }

    /// Adds a keyframe (its pose as the tracker reported it, and its features). When a loop
    /// is closed, returns the correction the caller must apply to the tracker before the
    /// next frame (see [`Correction`]); the loop closer assumes it is applied.
    pub fn add_keyframe(
        &mut self,
        frame: usize,
        t_world_cam: &Pose,
        features: &Features,
    ) -> Option<Correction> {
        let odom = self.fix.inverse().compose(&sim3_of(t_world_cam));
        let opt = match self.keyframes.last() {
            // Chain the odometry onto the previous keyframe's best estimate.
            Some(prev) => prev.opt.compose(&prev.odom.inverse().compose(&odom)),
            None => odom,
        };
        let d = features.dim;
        if d < 16 || features.descriptors.len() != features.len() * d {
            self.disabled.get_or_insert_with(|| {
                format!("loop closure needs float descriptors; these features have {d}-value descriptors (ORB)")
            });
        }
        let desc = if self.disabled.is_some() {
            DMatrix::zeros(0, 0)
        } else {
            let mut m = DMatrix::from_row_slice(features.len(), d, &features.descriptors);
            for mut row in m.row_iter_mut() {
                let n = row.norm();
                if n > 0.0 {
                    row /= n;
                }
            }
            m
        };
        let index = self.keyframes.len();
        self.keyframes.push(KeyframeEntry {
            frame,
            odom,
            opt,
            keypoints: features.keypoints.clone(),
            desc,
            points: Vec::new(),
            vlad: None,
        });
        self.frames.push((frame, odom, index, *t_world_cam));
        if self.disabled.is_some() {
            return None;
        }
        self.triangulate(index);
        self.update_vocabulary();
        self.detect(index)
    }

    /// Triangulates keyframe `k`'s keypoints against the earlier keyframe (of the last four)
    /// with the widest baseline, using the odometry between them.
    fn triangulate(&mut self, k: usize) {
        let cur = &self.keyframes[k];
        let mut points = vec![None; cur.keypoints.len()];
        let best = (k.saturating_sub(4)..k).max_by(|&a, &b| {
            let da = (self.keyframes[a].odom.t - cur.odom.t).norm();
            let db = (self.keyframes[b].odom.t - cur.odom.t).norm();
            da.total_cmp(&db)
        });
        if let Some(m) = best {
            let other = &self.keyframes[m];
            // T_other_cur: maps points of the current camera into the other camera.
            let rel = other.odom.inverse().compose(&cur.odom);
            let (r, t) = (rel.r, rel.t / rel.s);
            let thr = 2.0 / self.calib.fx;
            for (a, b) in mutual_matches(&cur.desc, &other.desc, self.cfg.min_cosine) {
                let (x1, x2) = (
                    self.bearing(&cur.keypoints[a]),
                    self.bearing(&other.keypoints[b]),
                );
                let views = [(Mat3::identity(), Vec3::zeros(), x1), (r, t, x2)];
                let accepted =
                    triangulate_checked(&views, thr).filter(|tri| tri.parallax_deg > 1.0);
                if let Some(tri) = accepted {
                    points[a] = Some(tri.point);
                }
            }
        }
        self.keyframes[k].points = points;
    }

    fn update_vocabulary(&mut self) {
        if self.vocabulary.is_none() {
            if self.keyframes.len() < self.cfg.vocabulary_keyframes {
                return;
            }
            let rows: Vec<_> = self
                .keyframes
                .iter()
                .flat_map(|k| {
                    k.desc
                        .row_iter()
                        .step_by(2)
                        .map(|r| r.into_owned())
                        .collect::<Vec<_>>()
                })
                .collect();
            if rows.is_empty() {
                return;
            }
            let data = DMatrix::from_rows(&rows);
            let vocabulary = kmeans(&data, self.cfg.vocabulary_size, 10);
            tracing::debug!(
                words = vocabulary.nrows(),
                descriptors = rows.len(),
                "loop vocabulary trained"
            );
            self.vocabulary = Some(vocabulary);
        }
        if let Some(voc) = &self.vocabulary {
            for k in self.keyframes.iter_mut().filter(|k| k.vlad.is_none()) {
                k.vlad = Some(vlad(&k.desc, voc));
            }
        }
    }

    /// Verifies the best places for keyframe `j`; closes a loop once confirmed.
    fn detect(&mut self, j: usize) -> Option<Correction> {
        let q = self.keyframes[j].vlad.as_ref()?;
        let last = j.checked_sub(self.cfg.min_separation)?;
        let mut scored: Vec<(usize, f32)> = (0..=last)
            .filter_map(|i| self.keyframes[i].vlad.as_ref().map(|v| (i, dot(q, v))))
            .collect();
        scored.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let found = scored
            .iter()
            .take(self.cfg.candidates)
            .filter_map(|&(i, sim)| {
                self.verify(i, j).map(|(rel, inliers)| Detection {
                    keyframe: j,
                    matched: i,
                    rel,
                    inliers,
                    similarity: sim,
                })
            })
            .max_by_key(|d| d.inliers);
        let Some(det) = found else {
            self.pending.clear();
            return None;
        };
        tracing::debug!(
            query = self.keyframes[j].frame,
            matched = self.keyframes[det.matched].frame,
            inliers = det.inliers,
            "place recognised"
        );
        // Consistent with the previous keyframe's detection: the same stretch of the past.
        let consistent = self
            .pending
            .last()
            .is_some_and(|p| p.keyframe + 1 == j && p.matched.abs_diff(det.matched) <= 6);
        if !consistent {
            self.pending.clear();
        }
        self.pending.push(det);
        if self.pending.len() < self.cfg.consistency {
            return None;
        }
        let confirmed = std::mem::take(&mut self.pending);
        for d in &confirmed {
            let edge = LoopEdge {
                query_frame: self.keyframes[d.keyframe].frame,
                match_frame: self.keyframes[d.matched].frame,
                inliers: d.inliers,
                scale: d.rel.s,
                similarity: d.similarity,
            };
            tracing::info!(
                query = edge.query_frame,
                matched = edge.match_frame,
                inliers = edge.inliers,
                scale = edge.scale,
                "loop closed"
            );
            self.loops.push((d.matched, d.keyframe, d.rel, edge));
        }
        self.optimise();
        let cur = &self.keyframes[j];
        let to_corrected = cur.opt.compose(&cur.odom.inverse());
        // Relative to what the tracker already applied.
        let correction = to_corrected.compose(&self.fix.inverse());
        self.fix = to_corrected;
        Some(Correction {
            frame: cur.frame,
            sim3: correction,
        })
    }

    /// Sim(3) from keyframe `j`'s camera to keyframe `i`'s that best explains their common
    /// points (RANSAC over minimal triples, inliers by reprojection in both images), with its
    /// inlier count when it has enough.
    fn verify(&self, i: usize, j: usize) -> Option<(Sim3, usize)> {
        let (a, b) = (&self.keyframes[i], &self.keyframes[j]);
        let pairs: Vec<(usize, usize, Vec3, Vec3)> =
            mutual_matches(&a.desc, &b.desc, self.cfg.min_cosine)
                .into_iter()
                .filter_map(|(ka, kb)| {
                    Some((
                        ka,
                        kb,
                        a.points.get(ka).copied().flatten()?,
                        b.points.get(kb).copied().flatten()?,
                    ))
                })
                .collect();
        tracing::trace!(
            query = b.frame,
            candidate = a.frame,
            pairs = pairs.len(),
            "loop candidate"
        );
        if pairs.len() < self.cfg.min_inliers {
            return None;
        }
        let thr2 = self.cfg.reprojection_px * self.cfg.reprojection_px;
        let inliers_of = |s: &Sim3| -> Vec<usize> {
            let inv = s.inverse();
            pairs
                .iter()
                .enumerate()
                .filter(|(_, (ka, kb, pa, pb))| {
                    let ok = |p: Option<(f64, f64)>, kp: &[f32; 2]| {
                        p.is_some_and(|(u, v)| {
                            (u - kp[0] as f64).powi(2) + (v - kp[1] as f64).powi(2) < thr2
                        })
                    };
                    ok(self.project(&s.transform(pb)), &a.keypoints[*ka])
                        && ok(self.project(&inv.transform(pa)), &b.keypoints[*kb])
                })
                .map(|(n, _)| n)
                .collect()
        };
        let fit = |idx: &[usize]| -> Option<Sim3> {
            let xs: Vec<Vec3> = idx.iter().map(|&n| pairs[n].3).collect();
            let ys: Vec<Vec3> = idx.iter().map(|&n| pairs[n].2).collect();
            let s = umeyama(&xs, &ys, true).ok()?;
            (s.scale.is_finite() && s.scale > 0.0).then(|| Sim3 {
                r: s.rotation_matrix(),
                t: s.translation,
                s: s.scale,
            })
        };
        let mut state = (i as u64) << 32 | j as u64;
        let mut pick = |n: usize| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as usize) % n
        };
        let mut best: Option<(Sim3, Vec<usize>)> = None;
        for _ in 0..300 {
            let s = [pick(pairs.len()), pick(pairs.len()), pick(pairs.len())];
            if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
                continue;
            }
            let Some(model) = fit(&s) else { continue };
            let inl = inliers_of(&model);
            if best.as_ref().is_none_or(|b| inl.len() > b.1.len()) {
                best = Some((model, inl));
            }
        }
        let (mut model, mut inliers) = best?;
        tracing::trace!(
            query = b.frame,
            candidate = a.frame,
            pairs = pairs.len(),
            inliers = inliers.len(),
            "loop candidate verified"
        );
        if inliers.len() < self.cfg.min_inliers {
            return None;
        }
        // Refit on the inliers while that explains at least as many points.
        for _ in 0..2 {
            let Some(refit) = fit(&inliers) else { break };
            let inl = inliers_of(&refit);
            if inl.len() < inliers.len() {
                break;
            }
            (model, inliers) = (refit, inl);
        }
        Some((model, inliers.len()))
    }

    /// Sim(3) pose graph over every keyframe: odometry between neighbours, the loops (Cauchy
    /// kernel against a wrong one), the first keyframe anchored.
    fn optimise(&mut self) {
        let n = self.keyframes.len();
        let values: Vec<Sim3> = self.keyframes.iter().map(|k| k.opt).collect();
        let mut graph = PoseGraph::<Sim3, 7>::new((0..n).collect(), values);
        let info = |rot: f64, trans: f64, scale: f64| {
            let v = [rot, rot, rot, trans, trans, trans, scale];
            nalgebra::SMatrix::<f64, 7, 7>::from_diagonal(&SVector::<f64, 7>::from_fn(|r, _| {
                1.0 / (v[r] * v[r])
            }))
        };
        for k in 1..n {
            let z = self.keyframes[k - 1]
                .odom
                .inverse()
                .compose(&self.keyframes[k].odom);
            let step = z.t.norm().max(1e-3);
            if let Ok(f) = Between::new(k - 1, k, z, &info(0.002, 0.02 * step, 0.005)) {
                graph.between.push(f);
            }
        }
        let first_loop = graph.between.len();
        for (i, j, rel, _) in &self.loops {
            let step = rel.t.norm().max(1e-1);
            if let Ok(f) = Between::new(*i, *j, *rel, &info(0.01, 0.05 * step, 0.02)) {
                graph.between.push(f);
            }
        }
        graph
            .priors
            .push(Prior::with_variances(0, self.keyframes[0].opt, &[1e-8; 7]));
        // Least squares first: from the odometry guess a true loop's residual is as large as
        // the drift, and a robust kernel would discard it. Then Cauchy from that solution, so
        // a loop that disagrees with the others loses its weight.
        for stage in 0..2 {
            if stage == 1 {
                for f in graph.between.iter_mut().skip(first_loop) {
                    f.kernel = Kernel::Cauchy(1.0);
                }
            }
            let Ok(mut lm) = Lm::new(&mut graph, LmParams::default()) else {
                return;
            };
            let summary = lm.optimize();
            tracing::debug!(
                stage,
                initial = summary.initial_error,
                last = summary.final_error,
                iterations = summary.iterations,
                "loop pose graph"
            );
        }
        for (k, v) in self.keyframes.iter_mut().zip(graph.values) {
            k.opt = v;
        }
    }

    /// The corrected pose `T_world_cam` of every frame recorded so far, in frame order: each
    /// frame moves with its keyframe. Until a loop is closed these are the poses as reported.
    pub fn trajectory(&self) -> Vec<(usize, Pose)> {
        if self.loops.is_empty() {
            return self.frames.iter().map(|f| (f.0, f.3)).collect();
        }
        self.frames
            .iter()
            .map(|(frame, odom, k, _)| {
                let kf = &self.keyframes[*k];
                let corrected = kf.opt.compose(&kf.odom.inverse()).compose(odom);
                (*frame, pose_of(&corrected))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutual_matches_pair_equal_rows() {
        let a = DMatrix::<f32>::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 0.6, 0.8]);
        let b = DMatrix::<f32>::from_row_slice(2, 2, &[0.0, 1.0, 1.0, 0.0]);
        let m = mutual_matches(&a, &b, 0.9);
        assert_eq!(m, vec![(0, 1), (1, 0)]);
    }

    #[test]
    fn vlad_is_unit_and_discriminative() {
        let data =
            DMatrix::<f32>::from_fn(200, 8, |i, j| (((i * 7 + j * 3) % 11) as f32 - 5.0) / 5.0);
        let voc = kmeans(&data, 4, 5);
        assert_eq!(voc.nrows(), 4);
        let v1 = vlad(&data.rows(0, 100).into_owned(), &voc);
        let v2 = vlad(&data.rows(100, 100).into_owned(), &voc);
        assert!((dot(&v1, &v1) - 1.0).abs() < 1e-4);
        assert!(dot(&v1, &v2) <= 1.0 + 1e-4);
        // Deterministic.
        assert_eq!(kmeans(&data, 4, 5), voc);
    }
}
