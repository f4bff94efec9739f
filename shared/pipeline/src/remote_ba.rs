//! The tracker's local bundle adjustments solved in the back-end process.
//!
//! At each new keyframe the tracker builds its local BA window as it does in one process;
//! in the daemon, [`RemoteBa`] sends that problem to the back end (`ba_problems`), whose
//! [`BaServer`] solves it with the same code and answers (`ba_solutions`). Every number
//! crosses as an `f64`, so the solution is the one the tracker would have computed: the run
//! stays bit-identical to `supermvo run --mode inprocess`. When no back end listens (it is
//! restarting) or none answers within the gap timeout, the tracker solves the problem
//! itself, with the same result, so a dead back end costs time, never a different
//! trajectory. In real time the tracker does not wait: [`LateSolutions`] applies each
//! solution when it arrives, as ORB-SLAM's local mapping thread updates the map beside
//! tracking.

use crate::common::{send_slice, StageContext};
use anyhow::{bail, Context, Result};
use std::io::Write;
use std::time::{Duration, Instant};
use supermvo_geometry::{Mat3, Pose, Vec3};
use supermvo_messages::iceoryx2::port::publisher::Publisher;
use supermvo_messages::iceoryx2::port::subscriber::Subscriber;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{FrameHeader, Ipc, MessageError, Status, Topic};
use supermvo_vo::ba::{BaOutcome, BaSolver, LocalBa, Observation};
use supermvo_vo::tracker::Tracker;

/// Values before the poses in a problem: counts of poses, points and observations, the
/// iterations and the Huber threshold.
const PROBLEM_HEAD: usize = 5;
/// Values before the poses in a solution: counts of poses and points, and the two costs.
const SOLUTION_HEAD: usize = 4;

/// A problem as `f64`s: `[poses, points, observations, iterations, huber]`, then each
/// `T_cam_world` (rotation row-major, translation), the fixed flags, the points and the
/// observations (`keyframe, point, bearing`).
pub fn encode_problem(ba: &LocalBa, iterations: usize) -> Vec<f64> {
    let mut v = Vec::with_capacity(
        PROBLEM_HEAD + 13 * ba.poses.len() + 3 * ba.points.len() + 5 * ba.observations.len(),
    );
    v.extend([
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

/// The problem of [`encode_problem`] and its iterations; an error for a malformed one.
pub fn decode_problem(v: &[f64]) -> Result<(LocalBa, usize)> {
    let Some(head) = v.get(..PROBLEM_HEAD) else {
        bail!("a local BA problem of {} values has no header", v.len());
    };
    let count = |x: f64| x as usize;
    let (np, nx, no) = (count(head[0]), count(head[1]), count(head[2]));
    if v.len() != PROBLEM_HEAD + 13 * np + 3 * nx + 5 * no {
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
        huber: head[4],
    };
    Ok((ba, count(head[3])))
}

/// A solved problem's poses, points and costs as `f64`s.
pub fn encode_solution(ba: &LocalBa, (before, after): (f64, f64)) -> Vec<f64> {
    let mut v = Vec::with_capacity(SOLUTION_HEAD + 12 * ba.poses.len() + 3 * ba.points.len());
    v.extend([ba.poses.len() as f64, ba.points.len() as f64, before, after]);
    ba.poses.iter().for_each(|p| push_pose(&mut v, p));
    ba.points.iter().for_each(|p| v.extend(p.iter()));
    v
}

/// A solution of [`encode_solution`]: the poses, the points and the costs.
pub type Solution = (Vec<Pose>, Vec<Vec3>, (f64, f64));

/// Reads a solution of [`encode_solution`]; an error for a malformed one.
pub fn decode_solution(v: &[f64]) -> Result<Solution> {
    let Some(head) = v.get(..SOLUTION_HEAD) else {
        bail!("a local BA solution of {} values has no header", v.len());
    };
    let (np, nx) = (head[0] as usize, head[1] as usize);
    if v.len() != SOLUTION_HEAD + 12 * np + 3 * nx {
        bail!(
            "a local BA solution of {} values does not hold {np} poses and {nx} points",
            v.len()
        );
    }
    let mut rest = &v[SOLUTION_HEAD..];
    let poses = (0..np).map(|_| take_pose(&mut rest)).collect();
    let points = (0..nx).map(|_| take_vec3(&mut rest)).collect();
    Ok((poses, points, (head[2], head[3])))
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

type Port = supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
    Ipc,
    [f64],
    FrameHeader,
>;

/// Tracking's side: hands each local BA to the back end and waits for its solution, or
/// (real time) goes on while [`LateSolutions`] brings it.
pub struct RemoteBa {
    service: Port,
    problems: Publisher<Ipc, [f64], FrameHeader>,
    /// The solutions waited for; `None`: not waited for.
    solutions: Option<Subscriber<Ipc, [f64], FrameHeader>>,
    next_id: u64,
    timeout: Duration,
}

impl std::fmt::Debug for RemoteBa {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "RemoteBa({} sent)", self.next_id)
    }
}

impl RemoteBa {
    /// The ports of the tracking stage of `ctx`; waits for each solution up to `timeout`.
    pub fn open(ctx: &StageContext, timeout: Duration) -> Result<Self> {
        let mut ba = Self::sender(ctx, timeout)?;
        ba.solutions = Some(ctx.slice_subscriber::<f64>(Topic::BaSolutions)?);
        Ok(ba)
    }

    /// The ports of the tracking stage of `ctx`, not waiting: the solutions come through
    /// the [`LateSolutions`] returned with it.
    pub fn open_deferred(ctx: &StageContext) -> Result<(Self, LateSolutions)> {
        let late = LateSolutions {
            solutions: ctx.slice_subscriber::<f64>(Topic::BaSolutions)?,
        };
        Ok((Self::sender(ctx, Duration::ZERO)?, late))
    }

    fn sender(ctx: &StageContext, timeout: Duration) -> Result<Self> {
        let service = ctx
            .services
            .slice_topic::<f64>(&ctx.node, Topic::BaProblems, false)?;
        let problems = service
            .publisher_builder()
            .initial_max_slice_len(1 << 14)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| MessageError::ipc("local BA publisher", e))?;
        Ok(Self {
            service,
            problems,
            solutions: None,
            next_id: 0,
            timeout,
        })
    }

    fn back_end_listens(&self) -> bool {
        self.service.dynamic_config().number_of_subscribers() > 0
    }

    /// Sends `ba`: its id, or `None` when no back end listens or the send fails.
    fn send(&mut self, ba: &LocalBa, iterations: usize) -> Option<u64> {
        if !self.back_end_listens() {
            return None;
        }
        let id = self.next_id;
        self.next_id += 1;
        let h = FrameHeader::new(id, 0, 0.0, Status::Ok);
        match send_slice(&self.problems, h, &encode_problem(ba, iterations)) {
            Ok(()) => Some(id),
            Err(e) => {
                tracing::warn!("local BA {id} not sent ({e:#}); solved here");
                None
            }
        }
    }

    /// Waits for the solution of `id` and writes it into `ba`: `None` when none comes in
    /// time or the back end goes away.
    fn wait_for(
        &self,
        solutions: &Subscriber<Ipc, [f64], FrameHeader>,
        id: u64,
        ba: &mut LocalBa,
    ) -> Option<(f64, f64)> {
        let deadline = Instant::now() + self.timeout;
        while Instant::now() < deadline {
            match solutions.receive() {
                Ok(Some(s)) if s.user_header().seq == id => {
                    return match apply_solution(s.payload(), ba) {
                        Ok(costs) => Some(costs),
                        Err(e) => {
                            tracing::warn!("local BA {id}: {e:#}; solved here");
                            None
                        }
                    };
                }
                Ok(Some(_)) => {} // the answer to a problem already solved here
                Ok(None) if !self.back_end_listens() => {
                    tracing::warn!("local BA {id}: the back end went away; solved here");
                    return None;
                }
                Ok(None) => std::thread::sleep(Duration::from_micros(100)),
                Err(e) => {
                    tracing::warn!(
                        "local BA {id}: receiving the solution failed ({e}); solved here"
                    );
                    return None;
                }
            }
        }
        tracing::warn!(
            "local BA {id}: no solution from the back end within {} ms; solved here",
            self.timeout.as_millis()
        );
        None
    }
}

impl BaSolver for RemoteBa {
    fn solve(&mut self, ba: &mut LocalBa, iterations: usize) -> BaOutcome {
        let solved = match (self.send(ba, iterations), &self.solutions) {
            (Some(id), None) => return BaOutcome::Deferred(id),
            (Some(id), Some(solutions)) => self.wait_for(solutions, id, ba),
            (None, _) => None,
        };
        let (before, after) = solved.unwrap_or_else(|| ba.solve(iterations));
        BaOutcome::Solved(before, after)
    }
}

/// Real time: the solutions of the windows handed off, applied to the tracker as they come.
pub struct LateSolutions {
    solutions: Subscriber<Ipc, [f64], FrameHeader>,
}

impl std::fmt::Debug for LateSolutions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("LateSolutions")
    }
}

impl LateSolutions {
    /// Applies every solution received (the tracker drops one a newer window replaced or a
    /// loop correction outdated); how many were applied.
    pub fn apply(&self, tracker: &mut Tracker) -> Result<usize> {
        let mut applied = 0;
        while let Some(s) = self
            .solutions
            .receive()
            .map_err(|e| MessageError::ipc("local BA solutions", e))?
        {
            let id = s.user_header().seq;
            match decode_solution(s.payload()) {
                Ok((poses, points, _)) => {
                    applied += tracker.apply_local_ba(id, &poses, &points) as usize;
                }
                Err(e) => tracing::warn!("local BA {id}: {e:#}; not applied"),
            }
        }
        Ok(applied)
    }
}

/// The back end's record of the local BAs it solved, in the output folder: one line each
/// (`id,keyframes,fixed,points,observations,cost_before,cost_after,ms`).
pub const LOG_FILE: &str = "local_ba.csv";

/// The back end's side: solves every problem received and answers it.
pub struct BaServer {
    problems: Subscriber<Ipc, [f64], FrameHeader>,
    solutions: Publisher<Ipc, [f64], FrameHeader>,
    log: std::fs::File,
}

impl std::fmt::Debug for BaServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BaServer")
    }
}

impl BaServer {
    /// The ports of the back-end stage of `ctx`, logging to [`LOG_FILE`] in `out`.
    pub fn open(ctx: &StageContext, out: &std::path::Path) -> Result<Self> {
        let path = out.join(LOG_FILE);
        let fresh = !path.exists();
        let mut log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        if fresh {
            writeln!(
                log,
                "id,keyframes,fixed,points,observations,cost_before,cost_after,ms"
            )?;
        }
        let solutions = ctx
            .services
            .slice_topic::<f64>(&ctx.node, Topic::BaSolutions, false)?
            .publisher_builder()
            .initial_max_slice_len(1 << 13)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| MessageError::ipc("local BA solutions publisher", e))?;
        Ok(Self {
            problems: ctx.slice_subscriber::<f64>(Topic::BaProblems)?,
            solutions,
            log,
        })
    }

    /// Solves and answers every problem waiting; how many. A malformed problem is logged
    /// and left unanswered (the tracker then solves it itself).
    pub fn serve(&mut self) -> Result<usize> {
        let mut served = 0;
        while let Some(s) = self
            .problems
            .receive()
            .map_err(|e| MessageError::ipc("local BA problems", e))?
        {
            let h = *s.user_header();
            let (mut ba, iterations) = match decode_problem(s.payload()) {
                Ok(p) => p,
                Err(e) => {
                    tracing::warn!("local BA {}: {e:#}; not solved", h.seq);
                    continue;
                }
            };
            drop(s);
            let started = Instant::now();
            let costs = ba.solve(iterations);
            send_slice(&self.solutions, h, &encode_solution(&ba, costs))?;
            let fixed = ba.fixed.iter().filter(|&&f| f).count();
            writeln!(
                self.log,
                "{},{},{fixed},{},{},{:e},{:e},{:.3}",
                h.seq,
                ba.poses.len(),
                ba.points.len(),
                ba.observations.len(),
                costs.0,
                costs.1,
                started.elapsed().as_secs_f64() * 1e3
            )?;
            served += 1;
        }
        Ok(served)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)] // test code
    use super::*;

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
        let (decoded, iterations) = decode_problem(&encode_problem(&ba, 10)).unwrap();
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
        assert!(decode_problem(&v[..3]).is_err());
        assert!(decode_problem(&v[..v.len() - 1]).is_err());
        let mut bad = v.clone();
        let first_observation = v.len() - 5 * ba.observations.len();
        bad[first_observation] = 7.0; // keyframe 7 of 3
        assert!(decode_problem(&bad).is_err());

        let mut target = ba.clone();
        let solution = encode_solution(&ba, (1.0, 0.5));
        assert!(apply_solution(&solution[..solution.len() - 3], &mut target).is_err());
        assert_eq!(format!("{target:?}"), format!("{ba:?}"));
        assert_eq!(apply_solution(&solution, &mut target).unwrap(), (1.0, 0.5));
    }
}
