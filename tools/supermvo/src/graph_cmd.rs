//! `supermvo graph optimize`.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::time::Instant;
use supermvo_optim::{
    read_g2o, write_g2o, G2oGraph, Lm, LmParams, LmSummary, Prior, PRIOR_VARIANCES_SE2,
    PRIOR_VARIANCES_SE3,
};

/// Arguments of `supermvo graph`.
#[derive(Debug, Args)]
pub struct GraphArgs {
    #[command(subcommand)]
    command: GraphCommand,
}

#[derive(Debug, Subcommand)]
enum GraphCommand {
    /// Optimise a g2o pose graph with Levenberg-Marquardt (GTSAM's defaults), the first
    /// vertex anchored by a prior (variances 1e-6 rad^2, 1e-4 m^2).
    Optimize {
        /// Input graph (VERTEX_SE3:QUAT/EDGE_SE3:QUAT or VERTEX_SE2/EDGE_SE2).
        file: PathBuf,
        /// Write the optimised graph here.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write {initial_error, final_error, iterations, seconds} as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Maximum iterations.
        #[arg(long, default_value_t = 100)]
        max_iterations: usize,
    },
}

fn optimize<G: supermvo_optim::lie::LieGroup<D>, const D: usize>(
    g: &mut supermvo_optim::PoseGraph<G, D>,
    variances: &[f64; D],
    params: LmParams,
) -> Result<LmSummary> {
    if g.values.is_empty() {
        anyhow::bail!("graph has no vertices");
    }
    let anchor = Prior::with_variances(0, g.values[0], variances);
    g.priors.push(anchor);
    let loose = g.unanchored();
    if let Some(first) = loose.first() {
        anyhow::bail!(
            "the graph is not connected: {} of {} vertices (the first is vertex {first}) have no chain of edges to vertex {}, so the optimisation cannot place them; is the file truncated or an edge missing?",
            loose.len(),
            g.values.len(),
            g.keys[0]
        );
    }
    let mut lm = Lm::new(g, params)?;
    Ok(lm.optimize())
}

/// Runs `supermvo graph`.
pub fn run(args: &GraphArgs) -> Result<()> {
    let GraphCommand::Optimize {
        file,
        out,
        json,
        max_iterations,
    } = &args.command;
    let (mut graph, report) = read_g2o(file)?;
    for (tag, n) in &report.unknown_tags {
        eprintln!(
            "warning: {}: skipped {n} line(s) with unknown tag {tag}",
            file.display()
        );
    }
    let params = LmParams {
        max_iterations: *max_iterations,
        ..Default::default()
    };
    let start = Instant::now();
    let (summary, vertices, edges) = match &mut graph {
        G2oGraph::Spatial(g) => (
            optimize(g, &PRIOR_VARIANCES_SE3, params)
                .with_context(|| file.display().to_string())?,
            g.values.len(),
            g.between.len(),
        ),
        G2oGraph::Planar(g) => (
            optimize(g, &PRIOR_VARIANCES_SE2, params)
                .with_context(|| file.display().to_string())?,
            g.values.len(),
            g.between.len(),
        ),
    };
    let seconds = start.elapsed().as_secs_f64();
    outln!(
        "{}: {vertices} vertices, {edges} edges; error {:.6} -> {:.6} in {} iterations, {:.3} s{}",
        file.display(),
        summary.initial_error,
        summary.final_error,
        summary.iterations,
        seconds,
        if summary.converged {
            ""
        } else {
            " (iteration cap reached)"
        }
    );
    if let Some(p) = json {
        let v = serde_json::json!({
            "initial_error": summary.initial_error, "final_error": summary.final_error,
            "iterations": summary.iterations, "seconds": seconds, "converged": summary.converged,
            "vertices": vertices, "edges": edges,
        });
        std::fs::write(p, serde_json::to_string_pretty(&v)?)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    if let Some(p) = out {
        write_g2o(p, &graph)?;
    }
    Ok(())
}
