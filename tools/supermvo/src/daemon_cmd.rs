//! `supermvo monitor` and `supermvo inspect`: read-only views of running pipelines.

use anyhow::Result;
use clap::Args;
use std::time::Duration;
use supermvo_pipeline::monitor::{inspect, Monitor};

/// Arguments of `supermvo monitor`.
#[derive(Debug, Args)]
pub struct MonitorArgs {
    /// Pipeline name (`pipeline.name` of the running daemon).
    #[arg(long, default_value = "supermvo")]
    name: String,
    /// Seconds per summary line.
    #[arg(long, default_value_t = 1.0)]
    interval: f64,
    /// Stop after this many lines (default: until the stream ends or Ctrl-C).
    #[arg(long)]
    count: Option<usize>,
    /// One JSON object per line instead of text.
    #[arg(long)]
    json: bool,
}

/// Runs `supermvo monitor`.
pub fn monitor(args: &MonitorArgs) -> Result<()> {
    let m = Monitor::attach(&args.name)?;
    let interval = Duration::from_secs_f64(args.interval.clamp(0.05, 3600.0));
    let mut lines = 0;
    loop {
        let s = m.sample(interval)?;
        if args.json {
            outln!("{}", serde_json::to_string(&s)?);
        } else {
            let rates: Vec<String> = s
                .rates
                .iter()
                .map(|(k, r)| {
                    let t = s.median_ms.get(k).copied().unwrap_or(f64::NAN);
                    format!("{k} {r:.1}/s {t:.0}ms")
                })
                .collect();
            let pos = s
                .position
                .map(|p| format!("({:.2}, {:.2}, {:.2})", p[0], p[1], p[2]))
                .unwrap_or_else(|| "-".into());
            outln!(
                "seq {} {} at {pos} | {} | capture->pose {} | not processed {}",
                s.last_seq.map_or("-".into(), |v| v.to_string()),
                s.state.as_deref().unwrap_or("-"),
                rates.join(", "),
                s.end_to_end_ms.map_or("-".into(), |v| format!("{v:.0} ms")),
                s.not_processed
            );
        }
        lines += 1;
        if s.finished || args.count.is_some_and(|c| lines >= c) {
            return Ok(());
        }
    }
}

/// Arguments of `supermvo inspect`.
#[derive(Debug, Args)]
pub struct InspectArgs {
    /// JSON instead of text.
    #[arg(long)]
    json: bool,
}

/// Runs `supermvo inspect`.
pub fn inspect_cmd(args: &InspectArgs) -> Result<()> {
    let (nodes, services) = inspect()?;
    if args.json {
        outln!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({"nodes": nodes, "services": services})
            )?
        );
        return Ok(());
    }
    if nodes.is_empty() && services.is_empty() {
        outln!("no SuPerMVO pipeline is running");
        return Ok(());
    }
    outln!("nodes:");
    for n in &nodes {
        outln!("  {:<48} {}", n.name, n.state);
    }
    outln!("services:");
    for s in &services {
        outln!("  {:<48} {} nodes", s.name, s.nodes);
    }
    Ok(())
}
