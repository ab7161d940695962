//! What `pvsd eval` reports: DESIGN's JSON, a table for the terminal, and an
//! SVG plot of the trade (cull time against PVS size, misses marked).

use std::fmt;
use std::path::Path;

use plotters::prelude::*;
use serde::{Deserialize, Serialize};

/// The whole report (DESIGN "`pvsd eval --json` output", plus the frame-cost model).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct EvalReport {
    /// Scene id.
    pub scene: String,
    /// Walk kind.
    pub walk: String,
    /// Frames evaluated.
    pub frames: usize,
    /// Image size of the truth, `[w, h]`.
    pub resolution: [u32; 2],
    /// Modelled cost of a triangle in the frame-cost model, nanoseconds.
    pub cost_per_triangle_ns: f64,
    /// Objects seen only at coplanar ties, per frame (not counted as visible).
    pub mean_tie_objects: f64,
    /// Median time to render the ground truth of one frame, milliseconds.
    pub median_truth_ms: f64,
    /// One entry per method, in the order asked.
    pub methods: Vec<MethodReport>,
    /// Only for a region (`--radius`, `--angle`): how it was checked and
    /// what it saves a walking client.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<RegionReport>,
}

/// How an evaluation of region answers ran: each frame's answer is held
/// to the union of the truths of cameras sampled in its region.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RegionReport {
    /// The radius, scene units.
    pub radius: f64,
    /// The angle, degrees.
    pub angle: f64,
    /// Cameras whose truth each frame's answer was held to.
    pub samples_per_frame: usize,
    /// A client walking the walk at `walker_speed` m/s and 30 frames/s
    /// that asks again only when its eye leaves the ball or its frame
    /// turns past the angle: the share of its frames that are requests.
    pub request_share: f64,
    /// The walker's speed, scene units per second.
    pub walker_speed: f64,
}

/// One method's results over the walkthrough.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct MethodReport {
    /// The method as asked, options included (`gpu:contribution=0.001`).
    pub method: String,
    /// Its options.
    pub options: std::collections::BTreeMap<String, String>,
    /// Whether it promises never to drop a visible object.
    pub conservative: bool,
    /// Median cull time per frame, µs.
    pub median_cull_us: f64,
    /// 99th-percentile cull time per frame, µs.
    pub p99_cull_us: f64,
    /// Mean objects in its answer.
    pub mean_pvs: f64,
    /// Mean truth-visible objects.
    pub mean_truth: f64,
    /// Mean objects whose box touches the frustum, counted exactly by eval
    /// (the same for every method on the same frames).
    pub mean_in_frustum: f64,
    /// Truth-visible objects it dropped, summed over frames.
    pub misses: u64,
    /// Tie-only objects it dropped, summed over frames (not misses).
    pub ties: u64,
    /// Mean PVS / mean truth.
    pub overestimation: f64,
    /// 1 − mean PVS / mean in-frustum.
    pub culled_in_frustum_share: f64,
    /// Share of all pixels an image drawn from its answer gets wrong.
    pub wrong_pixel_share: f64,
    /// Mean triangles in its answer.
    pub mean_pvs_triangles: f64,
    /// Mean modelled frame cost: cull time + PVS triangles × cost per triangle, µs.
    pub mean_frame_cost_us: f64,
    /// Frustum culling's frame cost over this one's (when frustum ran).
    pub speedup: Option<f64>,
    /// Up to 8 `(frame, object)` misses, to say where to look.
    pub miss_examples: Vec<(usize, u32)>,
    /// Only for a region: its mean PVS over the same method's mean PVS for
    /// the walk's point views (the price of the region).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pvs_growth: Option<f64>,
}

impl fmt::Display for EvalReport {
    /// The table `pvsd eval` prints.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{}: {} walk, {} frames at {}x{}; truth {:.1} ms/frame (median); {:.1} tie-only objects/frame",
            self.scene,
            self.walk,
            self.frames,
            self.resolution[0],
            self.resolution[1],
            self.median_truth_ms,
            self.mean_tie_objects
        )?;
        if let Some(r) = &self.region {
            writeln!(
                f,
                "region: radius {} angle {}°; each answer held to {} sampled cameras' truth; a walker at {} m/s, 30 frames/s, asks on {:.1}% of its frames",
                r.radius,
                r.angle,
                r.samples_per_frame,
                r.walker_speed,
                r.request_share * 100.0
            )?;
        }
        writeln!(
            f,
            "{:<28} {:>4} {:>10} {:>10} {:>9} {:>9} {:>9} {:>7} {:>6} {:>7} {:>7} {:>8} {:>11} {:>8}",
            "method",
            "cons",
            "median µs",
            "p99 µs",
            "mean PVS",
            "truth",
            "frustum",
            "misses",
            "ties",
            "overest",
            "culled",
            "wrong px",
            "frame µs",
            "speedup"
        )?;
        for m in &self.methods {
            writeln!(
                f,
                "{:<28} {:>4} {:>10.1} {:>10.1} {:>9.1} {:>9.1} {:>9.1} {:>7} {:>6} {:>7.2} {:>6.1}% {:>7.3}% {:>11.1} {:>8}",
                m.method,
                if m.conservative { "yes" } else { "no" },
                m.median_cull_us,
                m.p99_cull_us,
                m.mean_pvs,
                m.mean_truth,
                m.mean_in_frustum,
                m.misses,
                m.ties,
                m.overestimation,
                m.culled_in_frustum_share * 100.0,
                m.wrong_pixel_share * 100.0,
                m.mean_frame_cost_us,
                m.speedup.map_or("-".to_string(), |s| format!("{s:.2}")),
            )?;
            if let Some(g) = m.pvs_growth {
                writeln!(f, "{:<28} PVS ×{g:.2} against point views", "")?;
            }
        }
        Ok(())
    }
}

/// Plots the trade: median cull time (x, µs) against mean PVS (y), one
/// labelled point per method, the truth as a line; methods with misses are
/// drawn as red crosses with their miss count.
pub fn write_svg(report: &EvalReport, path: &Path) -> Result<(), String> {
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
        root.fill(&WHITE)?;
        let x_max = report
            .methods
            .iter()
            .map(|m| m.median_cull_us)
            .fold(1.0, f64::max)
            * 1.25;
        let truth = report.methods.first().map_or(0.0, |m| m.mean_truth);
        let y_max = report
            .methods
            .iter()
            .map(|m| m.mean_pvs)
            .fold(truth, f64::max)
            .max(1.0)
            * 1.2;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "{}: {} walk, {} frames at {}x{}",
                    report.scene,
                    report.walk,
                    report.frames,
                    report.resolution[0],
                    report.resolution[1]
                ),
                ("sans-serif", 20),
            )
            .margin(20)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..x_max, 0.0..y_max)?;
        chart
            .configure_mesh()
            .x_desc("median cull time per frame (µs)")
            .y_desc("mean objects in the answer")
            .draw()?;
        chart
            .draw_series(LineSeries::new(
                [(0.0, truth), (x_max, truth)],
                BLUE.stroke_width(1),
            ))?
            .label(format!("truth-visible ({truth:.1})"))
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLUE));
        for m in &report.methods {
            let (x, y) = (m.median_cull_us, m.mean_pvs);
            let label = if m.misses > 0 {
                format!("{} ({} misses)", m.method, m.misses)
            } else {
                m.method.clone()
            };
            // The label sits beside its marker, not on it.
            let text = || Text::new(label.clone(), (8, -18), ("sans-serif", 14).into_font());
            if m.misses > 0 {
                let cross = Cross::new((0, 0), 6, RED.stroke_width(2));
                chart.draw_series([EmptyElement::at((x, y)) + cross + text()])?;
            } else {
                let dot = Circle::new((0, 0), 5, BLACK.filled());
                chart.draw_series([EmptyElement::at((x, y)) + dot + text()])?;
            }
        }
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| format!("cannot write {}: {e}", path.display()))
}
