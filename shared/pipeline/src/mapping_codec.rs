//! The local mapping's requests and replies between tracking and the back end as `f64`
//! slices (`mapping_requests`, `mapping_replies`): a keyframe's triangulations and its local
//! bundle adjustment. Every number crosses as an `f64`, so the back end computes exactly
//! what the tracker would have. The first value names the kind.

use anyhow::{bail, Result};
use supermvo_geometry::essential::Triangulated;
use supermvo_geometry::{Mat3, Pose, Vec3};
use supermvo_vo::ba::{LocalBa, Observation};
use supermvo_vo::mapping_solver::TriangulationBatch;

/// The kind of a local BA request or reply (its first value).
const BA: f64 = 0.0;
/// The kind of a triangulation request or reply.
const TRIANGULATION: f64 = 1.0;
/// Values before the poses in a BA problem: the kind, counts of poses, points and
/// observations, the iterations and the Huber threshold.
const PROBLEM_HEAD: usize = 6;
/// Values before the poses in a BA solution: the kind, counts of poses and points, the two
/// costs.
const SOLUTION_HEAD: usize = 5;
/// Values before the poses in a triangulation batch: the kind, counts of poses, queries and
/// views, the gate.
const BATCH_HEAD: usize = 5;
/// Values per triangulated point in a reply: found, the point, the parallax.
const ANSWER: usize = 5;

/// A request to the back end.
#[derive(Debug)]
pub enum Request {
    /// A local BA and its iterations.
    Ba(LocalBa, usize),
    /// A keyframe's triangulations.
    Triangulation(TriangulationBatch),
}

/// A problem as `f64`s: `[kind, poses, points, observations, iterations, huber]`, then each
/// `T_cam_world` (rotation row-major, translation), the fixed flags, the points and the
/// observations (`keyframe, point, bearing`).
pub fn encode_problem(ba: &LocalBa, iterations: usize) -> Vec<f64> {
    let mut v = Vec::with_capacity(
        PROBLEM_HEAD + 13 * ba.poses.len() + 3 * ba.points.len() + 5 * ba.observations.len(),
    );
    v.extend([
        BA,
        ba.poses.len() as f64,
        ba.points.len() as f64,
        ba.observations.len() as f64,
        iterations as f64,
        ba.huber,
    ]);
    ba.poses.iter().for_each(|p| push_pose(&mut v, p));
    v.extend(ba.fixed.iter().map(|&f| f as u8 as f64));
    ba.points.iter().for_each(|p| v.extend(p.iter()));
    for o in &ba.observations {
        v.extend([o.kf as f64, o.point as f64]);
        v.extend(o.bearing.iter());
    }
    v
}

/// A batch as `f64`s: `[kind, poses, queries, views, max_error]`, each `T_cam_world`, then
/// per query its number of views and each view (`pose, bearing`).
pub fn encode_batch(batch: &TriangulationBatch) -> Vec<f64> {
    let views: usize = batch.queries.iter().map(Vec::len).sum();
    let mut v =
        Vec::with_capacity(BATCH_HEAD + 12 * batch.poses.len() + batch.queries.len() + 4 * views);
    v.extend([
        TRIANGULATION,
        batch.poses.len() as f64,
        batch.queries.len() as f64,
        views as f64,
        batch.max_error,
    ]);
    batch.poses.iter().for_each(|p| push_pose(&mut v, p));
    for q in &batch.queries {
        v.push(q.len() as f64);
        for (k, b) in q {
            v.push(*k as f64);
            v.extend(b.iter());
        }
    }
    v
}

/// The request of [`encode_problem`] or [`encode_batch`]; an error for a malformed one.
pub fn decode_request(v: &[f64]) -> Result<Request> {
    match v.first() {
        Some(&BA) => decode_problem(v).map(|(ba, it)| Request::Ba(ba, it)),
        Some(&TRIANGULATION) => decode_batch(v).map(Request::Triangulation),
        Some(kind) => bail!("a local-mapping request of unknown kind {kind}"),
        None => bail!("an empty local-mapping request"),
    }
}

fn decode_problem(v: &[f64]) -> Result<(LocalBa, usize)> {
    let Some(head) = v.get(..PROBLEM_HEAD) else {
        bail!("a local BA problem of {} values has no header", v.len());
    };
    let (np, nx, no) = (count(head[1]), count(head[2]), count(head[3]));
    if Some(v.len()) != sized(PROBLEM_HEAD, &[(13, np), (3, nx), (5, no)]) {
        bail!(
            "a local BA problem of {} values does not hold {np} poses, {nx} points and {no} observations",
            v.len()
        );
    }
    let mut rest = &v[PROBLEM_HEAD..];
    let poses = (0..np).map(|_| take_pose(&mut rest)).collect();
    let fixed = take(&mut rest, np).iter().map(|&f| f != 0.0).collect();
    let points = (0..nx).map(|_| take_vec3(&mut rest)).collect();
    let mut observations = Vec::with_capacity(no);
    for _ in 0..no {
        let ids = take(&mut rest, 2);
        let (kf, point) = (count(ids[0]), count(ids[1]));
        if kf >= np || point >= nx {
            bail!("a local BA observation names keyframe {kf} of {np} or point {point} of {nx}");
        }
        let bearing = take_vec3(&mut rest);
        observations.push(Observation { kf, point, bearing });
    }
    let ba = LocalBa {
        poses,
        fixed,
        points,
        observations,
        huber: head[5],
    };
    Ok((ba, count(head[4])))
}

fn decode_batch(v: &[f64]) -> Result<TriangulationBatch> {
    let Some(head) = v.get(..BATCH_HEAD) else {
        bail!("a triangulation batch of {} values has no header", v.len());
    };
    let (np, nq, nv) = (count(head[1]), count(head[2]), count(head[3]));
    if Some(v.len()) != sized(BATCH_HEAD, &[(12, np), (1, nq), (4, nv)]) {
        bail!(
            "a triangulation batch of {} values does not hold {np} poses, {nq} points and {nv} views",
            v.len()
        );
    }
    let mut rest = &v[BATCH_HEAD..];
    let poses = (0..np).map(|_| take_pose(&mut rest)).collect();
    let mut queries = Vec::with_capacity(nq);
    let mut left = nv;
    for _ in 0..nq {
        let n = count(take(&mut rest, 1)[0]);
        if n > left {
            bail!("a triangulation batch's points have more than its {nv} views");
        }
        left -= n;
        let mut q = Vec::with_capacity(n);
        for _ in 0..n {
            let k = count(take(&mut rest, 1)[0]);
            if k >= np {
                bail!("a triangulation view names pose {k} of {np}");
            }
            q.push((k, take_vec3(&mut rest)));
        }
        queries.push(q);
    }
    if left != 0 {
        bail!("a triangulation batch's points have fewer than its {nv} views");
    }
    Ok(TriangulationBatch {
        poses,
        queries,
        max_error: head[4],
    })
}

/// A solved problem's poses, points and costs as `f64`s.
pub fn encode_solution(ba: &LocalBa, (before, after): (f64, f64)) -> Vec<f64> {
    let mut v = Vec::with_capacity(SOLUTION_HEAD + 12 * ba.poses.len() + 3 * ba.points.len());
    v.extend([
        BA,
        ba.poses.len() as f64,
        ba.points.len() as f64,
        before,
        after,
    ]);
    ba.poses.iter().for_each(|p| push_pose(&mut v, p));
    ba.points.iter().for_each(|p| v.extend(p.iter()));
    v
}

/// A solution of [`encode_solution`]: the poses, the points and the costs.
pub type Solution = (Vec<Pose>, Vec<Vec3>, (f64, f64));

/// Reads a solution of [`encode_solution`]; an error for a malformed one.
pub fn decode_solution(v: &[f64]) -> Result<Solution> {
    let Some(head) = v.get(..SOLUTION_HEAD).filter(|h| h[0] == BA) else {
        bail!("a local BA solution of {} values has no header", v.len());
    };
    let (np, nx) = (count(head[1]), count(head[2]));
    if Some(v.len()) != sized(SOLUTION_HEAD, &[(12, np), (3, nx)]) {
        bail!(
            "a local BA solution of {} values does not hold {np} poses and {nx} points",
            v.len()
        );
    }
    let mut rest = &v[SOLUTION_HEAD..];
    let poses = (0..np).map(|_| take_pose(&mut rest)).collect();
    let points = (0..nx).map(|_| take_vec3(&mut rest)).collect();
    Ok((poses, points, (head[3], head[4])))
}

/// Writes the solution of [`encode_solution`] into `ba`; its costs. An error, leaving `ba`
/// as it was, when the solution does not fit the problem.
pub fn apply_solution(v: &[f64], ba: &mut LocalBa) -> Result<(f64, f64)> {
    let (poses, points, costs) = decode_solution(v)?;
    if poses.len() != ba.poses.len() || points.len() != ba.points.len() {
        bail!(
            "a local BA solution of {} poses and {} points does not fit {} poses and {} points",
            poses.len(),
            points.len(),
            ba.poses.len(),
            ba.points.len()
        );
    }
    (ba.poses, ba.points) = (poses, points);
    Ok(costs)
}

/// A batch's answers as `f64`s: `[kind, points]`, then per point whether it was
/// triangulated, the point and its parallax (zeros where not).
pub fn encode_answers(answers: &[Option<Triangulated>]) -> Vec<f64> {
    let mut v = Vec::with_capacity(2 + ANSWER * answers.len());
    v.extend([TRIANGULATION, answers.len() as f64]);
    for a in answers {
        match a {
            Some(t) => {
                v.push(1.0);
                v.extend(t.point.iter());
                v.push(t.parallax_deg);
            }
            None => v.extend([0.0; ANSWER]),
        }
    }
    v
}

/// The answers of [`encode_answers`]; an error for a malformed reply or one that does not
/// answer `queries` points.
pub fn decode_answers(v: &[f64], queries: usize) -> Result<Vec<Option<Triangulated>>> {
    let Some(head) = v.get(..2).filter(|h| h[0] == TRIANGULATION) else {
        bail!("a triangulation reply of {} values has no header", v.len());
    };
    let n = count(head[1]);
    if n != queries || Some(v.len()) != sized(2, &[(ANSWER, n)]) {
        bail!(
            "a triangulation reply of {} values does not answer {queries} points",
            v.len()
        );
    }
    Ok(v[2..]
        .chunks_exact(ANSWER)
        .map(|a| {
            (a[0] != 0.0).then(|| Triangulated {
                point: Vec3::new(a[1], a[2], a[3]),
                parallax_deg: a[4],
            })
        })
        .collect())
}

/// A count sent as an `f64` (a negative or non-finite one reads as an impossible size).
fn count(x: f64) -> usize {
    if x.is_finite() && x >= 0.0 {
        x as usize
    } else {
        usize::MAX
    }
}

/// `head` plus the sum of `per * n` for each `(per, n)`; `None` on overflow.
fn sized(head: usize, parts: &[(usize, usize)]) -> Option<usize> {
    parts
        .iter()
        .try_fold(head, |acc, &(per, n)| acc.checked_add(per.checked_mul(n)?))
}

fn push_pose(v: &mut Vec<f64>, p: &Pose) {
    for i in 0..3 {
        v.extend((0..3).map(|j| p.r[(i, j)]));
    }
    v.extend(p.t.iter());
}

fn take<'a>(rest: &mut &'a [f64], n: usize) -> &'a [f64] {
    let (head, tail) = rest.split_at(n);
    *rest = tail;
    head
}

fn take_vec3(rest: &mut &[f64]) -> Vec3 {
    let x = take(rest, 3);
    Vec3::new(x[0], x[1], x[2])
}

fn take_pose(rest: &mut &[f64]) -> Pose {
    let r = Mat3::from_row_slice(take(rest, 9));
    Pose::new(r, take_vec3(rest))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
    use super::*;
    use supermvo_geometry::{Mat3, Pose, Vec3};

    /// A small window: three keyframes along x (the first two fixed), eight points ahead,
    /// every point seen by every keyframe, the free keyframe and the points perturbed.
    fn window() -> LocalBa {
        let centres = [0.0, 1.0, 2.0];
        let truth: Vec<Vec3> = (0..8)
            .map(|i| {
                Vec3::new(
                    -2.0 + 0.6 * i as f64,
                    0.3 * (i % 3) as f64 - 0.3,
                    8.0 + i as f64,
                )
            })
            .collect();
        let poses: Vec<Pose> = centres
            .iter()
            .map(|&c| Pose::new(Mat3::identity(), Vec3::new(-c, 0.0, 0.0)))
            .collect();
        let mut observations = Vec::new();
        for (kf, pose) in poses.iter().enumerate() {
            for (point, x) in truth.iter().enumerate() {
                let c = pose.r * x + pose.t;
                observations.push(Observation {
                    kf,
                    point,
                    bearing: c / c.z,
                });
            }
        }
        let mut poses = poses;
        poses[2].t += Vec3::new(0.05, -0.02, 0.03);
        LocalBa {
            poses,
            fixed: vec![true, true, false],
            points: truth
                .iter()
                .map(|p| p + Vec3::new(0.05, 0.02, -0.1))
                .collect(),
            observations,
            huber: 2.0 / 700.0,
        }
    }

    #[test]
    fn a_problem_crosses_exactly_and_its_solution_is_the_local_one() {
        let ba = window();
        let Request::Ba(decoded, iterations) = decode_request(&encode_problem(&ba, 10)).unwrap()
        else {
            panic!("not a local BA");
        };
        assert_eq!(iterations, 10);
        assert_eq!(format!("{decoded:?}"), format!("{ba:?}"));

        let mut here = ba.clone();
        let costs_here = here.solve(10);
        assert!(
            costs_here.1 < 1e-3 * costs_here.0,
            "the window did not converge"
        );
        let mut there = decoded;
        let costs_there = there.solve(10);
        let solution = encode_solution(&there, costs_there);
        let mut received = ba.clone();
        let costs = apply_solution(&solution, &mut received).unwrap();
        assert_eq!(costs, costs_here);
        assert_eq!(format!("{received:?}"), format!("{here:?}"));
    }

    #[test]
    fn malformed_problems_and_solutions_are_refused() {
        let ba = window();
        let v = encode_problem(&ba, 10);
        assert!(decode_request(&v[..3]).is_err());
        assert!(decode_request(&v[..v.len() - 1]).is_err());
        let mut bad = v.clone();
        let first_observation = v.len() - 5 * ba.observations.len();
        bad[first_observation] = 7.0; // keyframe 7 of 3
        assert!(decode_request(&bad).is_err());

        let mut target = ba.clone();
        let solution = encode_solution(&ba, (1.0, 0.5));
        assert!(apply_solution(&solution[..solution.len() - 3], &mut target).is_err());
        assert_eq!(format!("{target:?}"), format!("{ba:?}"));
        assert_eq!(apply_solution(&solution, &mut target).unwrap(), (1.0, 0.5));
    }

    /// The window's keyframes and views as a triangulation batch: every point seen by all
    /// three, and one behind the cameras.
    fn batch() -> TriangulationBatch {
        let ba = window();
        let mut queries: Vec<Vec<(usize, Vec3)>> = (0..ba.points.len())
            .map(|p| {
                ba.observations
                    .iter()
                    .filter(|o| o.point == p)
                    .map(|o| (o.kf, o.bearing))
                    .collect()
            })
            .collect();
        queries.push(vec![
            (0, Vec3::new(0.1, 0.0, 1.0)),
            (1, Vec3::new(0.3, 0.0, 1.0)),
        ]);
        // the true poses: the window perturbs the third
        let mut poses = ba.poses;
        poses[2].t -= Vec3::new(0.05, -0.02, 0.03);
        TriangulationBatch {
            poses,
            queries,
            max_error: 2.0 / 700.0,
        }
    }

    #[test]
    fn a_triangulation_batch_crosses_exactly_and_its_answers_are_the_local_ones() {
        let batch = batch();
        let Request::Triangulation(decoded) = decode_request(&encode_batch(&batch)).unwrap() else {
            panic!("not a triangulation batch");
        };
        assert_eq!(decoded, batch);
        let here = batch.solve();
        let found = here.iter().flatten().count();
        assert_eq!(found, 8, "{here:?}");
        assert!(here[8].is_none());
        let there = decode_answers(&encode_answers(&decoded.solve()), batch.queries.len());
        assert_eq!(there.unwrap(), here);
        // a view of a pose the batch lacks triangulates to nothing (the tracker never sends
        // one; the decoder refuses it, below)
        let mut lacking = batch.clone();
        lacking.queries = vec![vec![
            (0, Vec3::new(0.1, 0.0, 1.0)),
            (7, Vec3::new(0.2, 0.0, 1.0)),
        ]];
        assert_eq!(lacking.solve(), vec![None]);
    }

    #[test]
    fn malformed_batches_and_answers_are_refused() {
        let batch = batch();
        let v = encode_batch(&batch);
        assert!(decode_request(&v[..4]).is_err());
        assert!(decode_request(&v[..v.len() - 1]).is_err());
        assert!(decode_request(&[]).is_err());
        assert!(decode_request(&[7.0, 0.0]).is_err());
        // the first point claims more views than the batch holds
        let first_count = 5 + 12 * batch.poses.len();
        let mut bad = v.clone();
        bad[first_count] = 1e6;
        assert!(decode_request(&bad).is_err());
        // a view names a pose the batch lacks
        let mut bad = v.clone();
        bad[first_count + 1] = 9.0;
        assert!(decode_request(&bad).is_err());
        // a negative count
        let mut bad = v.clone();
        bad[2] = -1.0;
        assert!(decode_request(&bad).is_err());

        let answers = encode_answers(&batch.solve());
        assert!(decode_answers(&answers, batch.queries.len() - 1).is_err());
        assert!(decode_answers(&answers[..answers.len() - 1], batch.queries.len()).is_err());
        // a BA solution is not a triangulation reply, nor the other way round
        assert!(decode_answers(&encode_solution(&window(), (1.0, 0.5)), 0).is_err());
        assert!(decode_solution(&answers).is_err());
    }
}
