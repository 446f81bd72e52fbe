//! `learner plot`: the paper's six training curves (Fig. 3) from a run's
//! `history.jsonl`, as one SVG: per-episode values over environment steps
//! (dots) and their moving average (line); or several runs' moving averages
//! in one figure, to compare methods.

use std::path::Path;

use plotters::prelude::*;

use crate::history::{read_records, HISTORY_FILE};

/// The six per-episode metrics of the paper's training figure, in panel order.
pub const CURVES: [(&str, &str); 6] = [
    ("interaction_success_rate", "interaction success rate"),
    ("interacted_object_rate", "interacted object rate"),
    (
        "interactable_annotation_rate",
        "interactable annotation rate",
    ),
    (
        "non_interactable_annotation_rate",
        "non-interactable annotation rate",
    ),
    ("affordance_iou", "affordance IoU (U-Net vs ground truth)"),
    ("object_accuracy", "object-level accuracy"),
];

/// One curve: (environment steps, value) per episode, in file order.
pub type Series = Vec<(f64, f64)>;

/// Reads every episode record of a history file into one series per curve.
pub fn read_curves(run_dir: &Path) -> anyhow::Result<Vec<Series>> {
    let mut curves = vec![Series::new(); CURVES.len()];
    for record in read_records(run_dir, Some("episode"))? {
        let steps = record["env_steps"].as_f64().unwrap_or(0.0);
        for ((key, _), series) in CURVES.iter().zip(&mut curves) {
            if let Some(v) = record["stats"][key].as_f64() {
                series.push((steps, v));
            }
        }
    }
    Ok(curves)
}

/// Trailing moving average over `window` points.
pub fn moving_average(series: &Series, window: usize) -> Series {
    let window = window.max(1);
    series
        .iter()
        .enumerate()
        .map(|(i, &(x, _))| {
            let from = (i + 1).saturating_sub(window);
            let part = &series[from..=i];
            (x, part.iter().map(|p| p.1).sum::<f64>() / part.len() as f64)
        })
        .collect()
}

/// Line colours of the runs in a comparison, in order (then repeated).
const RUN_COLOURS: [RGBColor; 6] = [
    RGBColor(214, 39, 40),
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

/// A run's name in a legend: its directory's last component.
fn run_name(run_dir: &Path) -> String {
    run_dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| run_dir.display().to_string())
}

/// Draws the six curves into `out` (an SVG file). One run: every episode as
/// a dot and the moving average as a line. Several runs (a comparison of
/// methods or settings): one moving-average line per run, with a legend.
/// Returns the number of episodes of the longest run.
pub fn plot(run_dirs: &[&Path], out: &Path, window: usize) -> anyhow::Result<usize> {
    anyhow::ensure!(!run_dirs.is_empty(), "no run directory to plot");
    let mut runs = Vec::with_capacity(run_dirs.len());
    for run_dir in run_dirs {
        let curves = read_curves(run_dir)?;
        anyhow::ensure!(
            curves.iter().any(|c| !c.is_empty()),
            "{} has no episode records yet: let the run report a few episodes first",
            run_dir.join(HISTORY_FILE).display()
        );
        runs.push((run_name(run_dir), curves));
    }
    let episodes = runs
        .iter()
        .flat_map(|(_, curves)| curves.iter().map(Vec::len))
        .max()
        .unwrap_or(0);
    let max_steps = runs
        .iter()
        .flat_map(|(_, curves)| curves.iter().flatten())
        .map(|p| p.0)
        .fold(1.0f64, f64::max);
    let root = SVGBackend::new(out, (1500, 860)).into_drawing_area();
    let draw =
        |e: Box<dyn std::error::Error + '_>| anyhow::anyhow!("drawing {}: {e}", out.display());
    root.fill(&WHITE).map_err(|e| draw(Box::new(e)))?;
    let comparison = runs.len() > 1;
    for (index, (panel, (_, title))) in root
        .split_evenly((2, 3))
        .iter()
        .zip(CURVES.iter())
        .enumerate()
    {
        let top = runs
            .iter()
            .flat_map(|(_, curves)| curves[index].iter().map(|p| p.1))
            .fold(0.0f64, f64::max);
        let y_max = if top <= 1.0 { 1.0 } else { top * 1.05 };
        let mut chart = ChartBuilder::on(panel)
            .caption(*title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(48)
            .build_cartesian_2d(0.0..max_steps, 0.0..y_max)
            .map_err(|e| draw(Box::new(e)))?;
        chart
            .configure_mesh()
            .x_desc("environment steps")
            .x_labels(5)
            .y_labels(6)
            .draw()
            .map_err(|e| draw(Box::new(e)))?;
        for (run, (name, curves)) in runs.iter().enumerate() {
            let series = &curves[index];
            let colour = if comparison {
                RUN_COLOURS[run % RUN_COLOURS.len()]
            } else {
                RED
            };
            if !comparison {
                chart
                    .draw_series(
                        series
                            .iter()
                            .map(|&p| Circle::new(p, 2, BLUE.mix(0.3).filled())),
                    )
                    .map_err(|e| draw(Box::new(e)))?;
            }
            let line = chart
                .draw_series(LineSeries::new(
                    moving_average(series, window),
                    colour.stroke_width(2),
                ))
                .map_err(|e| draw(Box::new(e)))?;
            if comparison {
                line.label(name.as_str()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
            }
        }
        if comparison && index == 0 {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(|e| draw(Box::new(e)))?;
        }
    }
    root.present().map_err(|e| draw(Box::new(e)))?;
    Ok(episodes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moving_average_trails_and_history_records_become_curves() {
        let s: Series = vec![(1.0, 0.0), (2.0, 1.0), (3.0, 2.0), (4.0, 3.0)];
        assert_eq!(
            moving_average(&s, 2),
            vec![(1.0, 0.0), (2.0, 0.5), (3.0, 1.5), (4.0, 2.5)]
        );
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join(HISTORY_FILE),
            "{\"kind\":\"episode\",\"env_steps\":100,\"stats\":{\"affordance_iou\":0.25}}\n\
             {\"kind\":\"ppo\",\"env_steps\":120}\n\
             {\"kind\":\"episode\",\"env_steps\":200,\"stats\":{\"affordance_iou\":0.5,\"object_accuracy\":0.75}}\n",
        )
        .unwrap();
        let curves = read_curves(dir.path()).unwrap();
        assert_eq!(curves[4], vec![(100.0, 0.25), (200.0, 0.5)]);
        assert_eq!(curves[5], vec![(200.0, 0.75)]);
        let svg = dir.path().join("curves.svg");
        assert_eq!(plot(&[dir.path()], &svg, 5).unwrap(), 2);
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("<svg") && text.contains("affordance IoU"));

        // Two runs: one line each, named in a legend.
        let other = tempfile::tempdir().unwrap();
        std::fs::write(
            other.path().join(HISTORY_FILE),
            "{\"kind\":\"episode\",\"env_steps\":300,\"stats\":{\"affordance_iou\":0.1}}\n",
        )
        .unwrap();
        assert_eq!(plot(&[dir.path(), other.path()], &svg, 5).unwrap(), 2);
        let text = std::fs::read_to_string(&svg).unwrap();
        for run in [dir.path(), other.path()] {
            assert!(
                text.contains(&run_name(run)),
                "legend lacks {}",
                run_name(run)
            );
        }

        std::fs::write(dir.path().join(HISTORY_FILE), "").unwrap();
        assert!(plot(&[dir.path()], &svg, 5)
            .unwrap_err()
            .to_string()
            .contains("no episode records"));
    }
}
