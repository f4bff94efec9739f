//! PNG figures of evaluated trajectories, drawn with plotters.
//!
//! * `trajectory_xz.png`: top-down (x-z, the ground plane of a forward-looking camera)
//!   overlay of the ground truth and every estimate.
//! * `xyz.png`: x, y, z against time.
//! * `rpy.png`: roll, pitch, yaw against time.
//! * `ape_<label>.png`: the estimate's path coloured by APE translation error.
//!
//! Text is rendered with a TrueType font read at run time: `SUPERMVO_FONT` if set, else
//! DejaVu Sans or Liberation Sans from the usual system directories.

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use supermvo_dataset::Trajectory;
use supermvo_eval::Evaluation;

/// Why a figure could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// No usable font.
    #[error("no TrueType font found for plot labels (tried {tried}); install one with 'apt-get install fonts-dejavu-core' or set SUPERMVO_FONT=/path/to/font.ttf")]
    NoFont {
        /// Paths tried.
        tried: String,
    },
    /// The output directory could not be created.
    #[error("{path}: {source}")]
    Io {
        /// Directory.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: std::io::Error,
    },
    /// Drawing failed.
    #[error("drawing {path}: {message}")]
    Draw {
        /// Figure being drawn.
        path: PathBuf,
        /// What failed.
        message: String,
    },
}

const FONT_CANDIDATES: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
];

fn ensure_font() -> Result<(), PlotError> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    let r = FONT.get_or_init(|| {
        let mut tried: Vec<String> = Vec::new();
        let env = std::env::var("SUPERMVO_FONT").ok();
        for cand in env.iter().map(String::as_str).chain(FONT_CANDIDATES) {
            tried.push(cand.to_string());
            let Ok(bytes) = std::fs::read(cand) else {
                continue;
            };
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                return Ok(());
            }
        }
        Err(tried.join(", "))
    });
    r.clone().map_err(|tried| PlotError::NoFont { tried })
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

fn draw_err<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> PlotError + '_ {
    move |e| PlotError::Draw {
        path: path.to_path_buf(),
        message: format!("{e:?}"),
    }
}

/// Time axis of a trajectory: seconds from the first stamp, or the pose index.
fn time_axis(t: &Trajectory) -> (Vec<f64>, &'static str) {
    match &t.stamps {
        Some(s) if !s.is_empty() => (s.iter().map(|x| x - s[0]).collect(), "time (s)"),
        _ => ((0..t.len()).map(|i| i as f64).collect(), "frame"),
    }
}

fn padded_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() || !hi.is_finite() {
        return 0.0..1.0;
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad)..(hi + pad)
}

/// Tick labels for an axis spanning `range`: as many decimals as its tick spacing needs
/// (about a tenth of the span: none for 130 m, one for 1.3 m), no "-0", and a true minus
/// sign, which the fonts space correctly where a hyphen before "1" made "-10" read "-1 0".
fn tick_formatter(range: &std::ops::Range<f64>) -> impl Fn(&f64) -> String {
    let step = ((range.end - range.start) / 10.0).abs().max(1e-9);
    let decimals = (-step.log10().floor()).clamp(0.0, 4.0) as usize;
    move |v: &f64| {
        let text = format!("{v:.decimals$}");
        if text
            .trim_start_matches('-')
            .chars()
            .all(|c| c == '0' || c == '.')
        {
            text.trim_start_matches('-').to_string()
        } else {
            text.replace('-', "\u{2212}")
        }
    }
}

/// Equal-aspect x-z ranges covering all trajectories.
fn xz_ranges(trajs: &[&Trajectory]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let xr = padded_range(trajs.iter().flat_map(|t| t.poses.iter().map(|p| p.t.x)));
    let zr = padded_range(trajs.iter().flat_map(|t| t.poses.iter().map(|p| p.t.z)));
    let half = 0.5 * (xr.end - xr.start).max(zr.end - zr.start);
    let (xc, zc) = (0.5 * (xr.start + xr.end), 0.5 * (zr.start + zr.end));
    ((xc - half)..(xc + half), (zc - half)..(zc + half))
}

/// Draws the series labels of a chart in the common style (white box, black border).
fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
}

/// A metric x-z chart.
type TopView<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A top-view (x-z) chart with equal-aspect ranges and labelled axes.
fn top_view_chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    caption: &str,
    caption_size: u32,
    trajs: &[&Trajectory],
) -> Result<TopView<'a, DB>, DrawingAreaErrorKind<DB::ErrorType>> {
    let (xr, zr) = xz_ranges(trajs);
    let (x_ticks, z_ticks) = (tick_formatter(&xr), tick_formatter(&zr));
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", caption_size))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(xr, zr)?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("z (m)")
        .x_label_formatter(&x_ticks)
        .y_label_formatter(&z_ticks)
        .draw()?;
    Ok(chart)
}

fn trajectory_xz(
    path: &Path,
    reference: &Trajectory,
    results: &[(String, Evaluation)],
) -> Result<(), PlotError> {
    let e = draw_err(path);
    let root = BitMapBackend::new(path, (900, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(&e)?;
    let mut all: Vec<&Trajectory> = vec![reference];
    all.extend(results.iter().map(|(_, ev)| &ev.estimate));
    let mut chart = top_view_chart(&root, "Trajectory, top view (x-z)", 24, &all).map_err(&e)?;
    // the estimates first and wide, the ground truth last and thin, so both stay visible
    // where they coincide
    for (i, (label, ev)) in results.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                ev.estimate.poses.iter().map(|p| (p.t.x, p.t.z)),
                c.stroke_width(3),
            ))
            .map_err(&e)?
            .label(label.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3)));
    }
    chart
        .draw_series(LineSeries::new(
            reference.poses.iter().map(|p| (p.t.x, p.t.z)),
            BLACK.stroke_width(1),
        ))
        .map_err(&e)?
        .label("ground truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    draw_legend(&mut chart).map_err(&e)?;
    root.present().map_err(&e)
}

/// Three stacked panels of a per-pose quantity against time, ground truth and estimates.
fn three_panels(
    path: &Path,
    title: &str,
    names: [&str; 3],
    value: impl Fn(&supermvo_geometry::Pose) -> [f64; 3],
    wrap: Option<f64>,
    reference: &Trajectory,
    results: &[(String, Evaluation)],
) -> Result<(), PlotError> {
    let e = draw_err(path);
    let root = BitMapBackend::new(path, (1100, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(&e)?;
    let (top, body) = root.split_vertically(40);
    top.titled(title, ("sans-serif", 24)).map_err(&e)?;
    let panels = body.split_evenly((3, 1));
    let (t_ref, t_label) = time_axis(reference);
    // estimates first and wide, the ground truth last and thin (visible where they coincide)
    let series: Vec<(String, RGBColor, u32, &Trajectory)> = results
        .iter()
        .enumerate()
        .map(|(i, (l, ev))| (l.clone(), PALETTE[i % PALETTE.len()], 3, &ev.estimate))
        .chain(std::iter::once((
            "ground truth".to_string(),
            BLACK,
            1,
            reference,
        )))
        .collect();
    for (k, area) in panels.iter().enumerate() {
        let vr = padded_range(
            series
                .iter()
                .flat_map(|(_, _, _, t)| t.poses.iter().map(|p| value(p)[k])),
        );
        let tr = padded_range(t_ref.iter().copied());
        let (t_ticks, v_ticks) = (tick_formatter(&tr), tick_formatter(&vr));
        let mut chart = ChartBuilder::on(area)
            .margin(8)
            .x_label_area_size(if k == 2 { 40 } else { 20 })
            .y_label_area_size(70)
            .build_cartesian_2d(tr, vr)
            .map_err(&e)?;
        let mut mesh = chart.configure_mesh();
        mesh.y_desc(names[k])
            .x_label_formatter(&t_ticks)
            .y_label_formatter(&v_ticks);
        if k == 2 {
            mesh.x_desc(t_label);
        }
        mesh.draw().map_err(&e)?;
        for (label, color, width, traj) in &series {
            // Associated trajectories share the reference's time axis, pose for pose. Angles
            // are drawn as separate runs between wraps so a jump from +180 to -180 degrees
            // does not streak across the panel.
            let pts: Vec<(f64, f64)> = t_ref
                .iter()
                .zip(&traj.poses)
                .map(|(t, p)| (*t, value(p)[k]))
                .collect();
            let mut runs: Vec<&[(f64, f64)]> = Vec::new();
            let mut start = 0;
            for i in 1..pts.len() {
                if wrap.is_some_and(|w| (pts[i].1 - pts[i - 1].1).abs() > w) {
                    runs.push(&pts[start..i]);
                    start = i;
                }
            }
            runs.push(&pts[start..]);
            let s = chart
                .draw_series(
                    runs.into_iter()
                        .map(|r| PathElement::new(r.to_vec(), color.stroke_width(*width))),
                )
                .map_err(&e)?;
            if k == 0 {
                let (c, w) = (*color, *width);
                s.label(label.as_str()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(w))
                });
            }
        }
        if k == 0 {
            draw_legend(&mut chart).map_err(&e)?;
        }
    }
    root.present().map_err(&e)
}

/// A perceptually ordered colour map (viridis, 5 stops, linear in between).
pub fn viridis(u: f64) -> RGBColor {
    const STOPS: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let u = if u.is_finite() {
        u.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = u * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |p: f64, q: f64| (p + (q - p) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

fn ape_path(path: &Path, label: &str, ev: &Evaluation) -> Result<(), PlotError> {
    let e = draw_err(path);
    let root = BitMapBackend::new(path, (1000, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(&e)?;
    let (main, bar) = root.split_horizontally(820);
    let errs = &ev.ape.trans.values;
    let (lo, hi) = (ev.ape.trans.stats.min, ev.ape.trans.stats.max);
    let span = (hi - lo).max(1e-12);
    let caption = format!("APE (translation) along the path: {label}");
    let mut chart =
        top_view_chart(&main, &caption, 22, &[&ev.reference, &ev.estimate]).map_err(&e)?;
    let poses = &ev.estimate.poses;
    chart
        .draw_series(poses.windows(2).zip(errs.windows(2)).map(|(p, v)| {
            let c = viridis((0.5 * (v[0] + v[1]) - lo) / span);
            PathElement::new(
                vec![(p[0].t.x, p[0].t.z), (p[1].t.x, p[1].t.z)],
                c.stroke_width(3),
            )
        }))
        .map_err(&e)?;
    // the ground truth over the coloured path, thin, so it shows where they coincide
    chart
        .draw_series(LineSeries::new(
            ev.reference.poses.iter().map(|p| (p.t.x, p.t.z)),
            BLACK.mix(0.7).stroke_width(1),
        ))
        .map_err(&e)?
        .label("ground truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.7)));
    draw_legend(&mut chart).map_err(&e)?;
    draw_colorbar(&bar, lo, hi).map_err(&e)?;
    root.present().map_err(&e)
}

fn draw_colorbar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    lo: f64,
    hi: f64,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let range = lo..hi.max(lo + 1e-12);
    let ticks = tick_formatter(&range);
    let mut chart = ChartBuilder::on(area)
        .margin_top(60)
        .margin_bottom(60)
        .margin_right(40)
        .y_label_area_size(85)
        .build_cartesian_2d(0.0..1.0, range)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .disable_x_axis()
        .y_label_formatter(&ticks)
        .y_desc("APE (m)")
        .y_label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .draw()?;
    let n = 100;
    chart.draw_series((0..n).map(|i| {
        let a = lo + (hi - lo) * i as f64 / n as f64;
        let b = lo + (hi - lo) * (i + 1) as f64 / n as f64;
        Rectangle::new(
            [(0.0, a), (1.0, b)],
            viridis(i as f64 / (n - 1) as f64).filled(),
        )
    }))?;
    Ok(())
}

fn sanitize(label: &str) -> String {
    label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Writes every figure for `results` (all evaluated against the same reference) into `dir`.
pub fn write_all(dir: &Path, results: &[(String, Evaluation)]) -> Result<Vec<PathBuf>, PlotError> {
    let Some((_, first)) = results.first() else {
        return Ok(Vec::new());
    };
    ensure_font()?;
    std::fs::create_dir_all(dir).map_err(|source| PlotError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let reference = &first.reference;
    let mut written = Vec::new();
    let p = dir.join("trajectory_xz.png");
    trajectory_xz(&p, reference, results)?;
    written.push(p);
    // Several estimates may have been associated with the reference differently; the time
    // plots use each evaluation's own associated reference length, so draw them only when
    // all share the first one's (always true for KITTI and for a single estimate).
    let same_len: Vec<(String, Evaluation)> = results
        .iter()
        .filter(|(_, ev)| ev.estimate.len() == reference.len())
        .cloned()
        .collect();
    let p = dir.join("xyz.png");
    three_panels(
        &p,
        "Position against time",
        ["x (m)", "y (m)", "z (m)"],
        |q| [q.t.x, q.t.y, q.t.z],
        None,
        reference,
        &same_len,
    )?;
    written.push(p);
    let p = dir.join("rpy.png");
    three_panels(
        &p,
        "Orientation against time (static x-y-z Euler angles)",
        ["roll (deg)", "pitch (deg)", "yaw (deg)"],
        |q| {
            let (r, pi, y) = supermvo_geometry::euler_rpy(&q.quaternion());
            [r.to_degrees(), pi.to_degrees(), y.to_degrees()]
        },
        Some(180.0),
        reference,
        &same_len,
    )?;
    written.push(p);
    for (label, ev) in results {
        let p = dir.join(format!("ape_{}.png", sanitize(label)));
        ape_path(&p, label, ev)?;
        written.push(p);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_endpoints() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(f64::NAN), RGBColor(68, 1, 84));
    }

    #[test]
    fn tick_labels_have_the_decimals_the_span_needs_and_no_negative_zero() {
        let metres = tick_formatter(&(-85.0..5.0));
        assert_eq!(metres(&-10.0), "\u{2212}10");
        assert_eq!(metres(&40.0), "40");
        assert_eq!(metres(&-0.0), "0");
        let small = tick_formatter(&(-0.1..1.2));
        assert_eq!(small(&-0.02), "0.0");
        assert_eq!(small(&-0.3), "\u{2212}0.3");
        assert_eq!(small(&0.8), "0.8");
        let tiny = tick_formatter(&(0.0..0.05));
        assert_eq!(tiny(&0.012), "0.012");
    }
}
