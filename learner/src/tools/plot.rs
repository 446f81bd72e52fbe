//! `learner plot`: the paper's six training curves (Fig. 3), the episode
//! return, the interaction attempt rate and why attempts fail, and the
//! U-Net's IoU and object-level accuracy per affordance, from a run's
//! `history.jsonl`, as one SVG: per-episode values over environment steps
//! (dots) and their moving average (line); or several runs' moving averages
//! in one figure, to compare methods; or groups of repeats (seeds) as their
//! mean with a min–max band.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use plotters::prelude::*;

use crate::history::{read_records, HISTORY_FILE};
use crate::tools::summary::Spread;

/// The per-episode metrics drawn, in panel order: the paper's six training
/// curves, then the return PPO maximises, how often the policy still
/// tries an interaction (what a reward that favours navigation erodes), and
/// the shares of attempts that fail for want of an approach (the object is
/// beyond the arm's reach) or of a better choice (the object does not afford
/// the interaction), and the U-Net's two scores per affordance plane (the
/// paper's Fig. 3 shows pick up's).
pub(crate) const CURVES: [(&str, &str); 14] = [
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
    ("episode_return", "episode return"),
    ("interaction_attempt_rate", "interaction attempts per step"),
    (
        "interaction_out_of_reach_rate",
        "attempts failed: beyond reach",
    ),
    (
        "interaction_unafforded_rate",
        "attempts failed: not afforded",
    ),
    ("pick_up_iou", "pick-up IoU"),
    ("push_iou", "push IoU"),
    ("pick_up_object_accuracy", "pick-up object-level accuracy"),
    ("push_object_accuracy", "push object-level accuracy"),
];

/// Panels per row of the figure (two rows).
const PANELS_PER_ROW: usize = CURVES.len().div_ceil(2);

/// One curve: (environment steps, value) per episode, in file order.
pub(crate) type Series = Vec<(f64, f64)>;

/// Reads every episode record of a history file into one series per curve.
pub(crate) fn read_curves(run_dir: &Path) -> anyhow::Result<Vec<Series>> {
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
pub(crate) fn moving_average(series: &Series, window: usize) -> Series {
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

/// Runs drawn as one line: one run, or repeats of one setting (seeds).
#[derive(Debug, Clone, PartialEq)]
pub struct RunGroup {
    /// The line's name in the legend (default: from the directories' names).
    pub label: Option<String>,
    /// Run directories, each holding a `history.jsonl`.
    pub dirs: Vec<PathBuf>,
}

impl FromStr for RunGroup {
    type Err = String;

    /// `[LABEL=]DIR[,DIR...]`: one run directory, or several (repeats of one
    /// setting) joined by commas; an optional name for the legend.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (label, dirs) = match s.split_once('=') {
            Some((label, dirs)) if !label.contains('/') => (Some(label.to_string()), dirs),
            _ => (None, s),
        };
        let dirs: Vec<PathBuf> = dirs.split(',').map(PathBuf::from).collect();
        if dirs.iter().any(|d| d.as_os_str().is_empty()) {
            return Err(format!(
                "{s:?}: expected [LABEL=]DIR[,DIR...] (an empty directory name)"
            ));
        }
        Ok(Self { label, dirs })
    }
}

impl RunGroup {
    /// The name in a legend: the label, else the run's directory name, else
    /// the repeats' names' common leading parts and their count.
    fn name(&self) -> String {
        if let Some(label) = &self.label {
            return label.clone();
        }
        let names: Vec<String> = self.dirs.iter().map(|d| run_name(d)).collect();
        if let [one] = names.as_slice() {
            return one.clone();
        }
        let common = names[1..].iter().fold(names[0].as_str(), |prefix, name| {
            let len = prefix
                .char_indices()
                .zip(name.chars())
                .take_while(|((_, a), b)| a == b)
                .last()
                .map_or(0, |((i, a), _)| i + a.len_utf8());
            &prefix[..len]
        });
        // Whole name parts only: "x-seed1", "x-seed2" → "x".
        let separators = ['-', '_', '.'];
        let whole = names.iter().all(|n| {
            n[common.len()..]
                .chars()
                .next()
                .is_none_or(|c| separators.contains(&c))
        });
        let common = if whole {
            common
        } else {
            common.rfind(separators).map_or("", |i| &common[..i])
        };
        let common = common.trim_end_matches(separators);
        let stem = if common.is_empty() { &names[0] } else { common };
        format!("{stem} ({} runs)", names.len())
    }
}

/// A group of repeats as one curve: at `points` steps evenly spread up to
/// where the shortest run ends, the mean, lowest and highest of the runs'
/// moving averages (each run's latest value at or before that step).
/// Steps before every run has a value are left out.
pub(crate) fn group_curve(
    runs: &[Series],
    window: usize,
    points: usize,
) -> Vec<(f64, f64, f64, f64)> {
    let averaged: Vec<Series> = runs
        .iter()
        .filter(|s| !s.is_empty())
        .map(|s| moving_average(s, window))
        .collect();
    if averaged.len() < runs.len() || runs.is_empty() {
        return Vec::new();
    }
    let start = averaged.iter().map(|s| s[0].0).fold(f64::MIN, f64::max);
    let end = averaged
        .iter()
        .map(|s| s[s.len() - 1].0)
        .fold(f64::MAX, f64::min);
    let points = points.max(2);
    (0..points)
        .map(|i| end * i as f64 / (points - 1) as f64)
        .filter(|&x| x >= start)
        .filter_map(|x| {
            let values = averaged
                .iter()
                .map(|s| s[s.partition_point(|p| p.0 <= x) - 1].1);
            Spread::of(values).map(|s| (x, s.mean, s.min, s.max))
        })
        .collect()
}

/// Points of a group's curve.
const GROUP_POINTS: usize = 200;

/// Episode dots drawn per curve at most: a panel is 500 pixels wide, so more
/// dots draw nothing new, and a long run's 5 000 episodes made a 3 MB file.
const MAX_DOTS: usize = 1_000;

/// Every k-th point of `series` (from the first), with k the smallest step
/// that keeps at most `max` points.
fn thinned(series: &[(f64, f64)], max: usize) -> impl Iterator<Item = (f64, f64)> + '_ {
    let step = series.len().div_ceil(max.max(1)).max(1);
    series.iter().copied().step_by(step)
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

/// Draws the curves into `out` (an SVG file). One run: every episode as
/// a dot and the moving average as a line. Several runs (a comparison of
/// methods or settings): one moving-average line per run, with a legend; a
/// group of repeats is drawn as their mean, in a band from their lowest to
/// their highest value. Returns the number of episodes of the longest run.
pub fn plot(groups: &[RunGroup], out: &Path, window: usize) -> anyhow::Result<usize> {
    anyhow::ensure!(
        groups.iter().any(|g| !g.dirs.is_empty()),
        "no run directory to plot"
    );
    let mut runs = Vec::with_capacity(groups.len());
    for group in groups {
        let mut curves_of_runs = Vec::with_capacity(group.dirs.len());
        for run_dir in &group.dirs {
            let curves = read_curves(run_dir)?;
            anyhow::ensure!(
                curves.iter().any(|c| !c.is_empty()),
                "{} has no episode records yet: let the run report a few episodes first",
                run_dir.join(HISTORY_FILE).display()
            );
            curves_of_runs.push(curves);
        }
        runs.push((group.name(), curves_of_runs));
    }
    let all_series = || {
        runs.iter()
            .flat_map(|(_, group)| group.iter().flat_map(|curves| curves.iter()))
    };
    let episodes = all_series().map(Vec::len).max().unwrap_or(0);
    let max_steps = all_series().flatten().map(|p| p.0).fold(1.0f64, f64::max);
    let root = SVGBackend::new(out, (500 * PANELS_PER_ROW as u32, 860)).into_drawing_area();
    let draw =
        |e: Box<dyn std::error::Error + '_>| anyhow::anyhow!("drawing {}: {e}", out.display());
    root.fill(&WHITE).map_err(|e| draw(Box::new(e)))?;
    let comparison = runs.len() > 1 || runs[0].1.len() > 1;
    for (index, (panel, (_, title))) in root
        .split_evenly((2, PANELS_PER_ROW))
        .iter()
        .zip(CURVES.iter())
        .enumerate()
    {
        let values = || {
            runs.iter()
                .flat_map(|(_, group)| group.iter().flat_map(|curves| curves[index].iter()))
                .map(|p| p.1)
        };
        let top = values().fold(0.0f64, f64::max);
        let bottom = values().fold(0.0f64, f64::min);
        let y_max = if top <= 1.0 { 1.0 } else { top * 1.05 };
        let y_min = bottom * 1.05;
        let mut chart = ChartBuilder::on(panel)
            .caption(*title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(48)
            .build_cartesian_2d(0.0..max_steps, y_min..y_max)
            .map_err(|e| draw(Box::new(e)))?;
        chart
            .configure_mesh()
            .x_desc("environment steps")
            .x_labels(5)
            .y_labels(6)
            .draw()
            .map_err(|e| draw(Box::new(e)))?;
        for (run, (name, group)) in runs.iter().enumerate() {
            let colour = if comparison {
                RUN_COLOURS[run % RUN_COLOURS.len()]
            } else {
                RED
            };
            let line = if let [curves] = group.as_slice() {
                let series = &curves[index];
                if !comparison {
                    chart
                        .draw_series(
                            thinned(series, MAX_DOTS)
                                .map(|p| Circle::new(p, 2, BLUE.mix(0.3).filled())),
                        )
                        .map_err(|e| draw(Box::new(e)))?;
                }
                moving_average(series, window)
            } else {
                let series: Vec<Series> =
                    group.iter().map(|curves| curves[index].clone()).collect();
                let curve = group_curve(&series, window, GROUP_POINTS);
                let band: Vec<(f64, f64)> = curve
                    .iter()
                    .map(|&(x, _, _, hi)| (x, hi))
                    .chain(curve.iter().rev().map(|&(x, _, lo, _)| (x, lo)))
                    .collect();
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        band,
                        colour.mix(0.15).filled(),
                    )))
                    .map_err(|e| draw(Box::new(e)))?;
                curve.iter().map(|&(x, mean, _, _)| (x, mean)).collect()
            };
            let line = chart
                .draw_series(LineSeries::new(line, colour.stroke_width(2)))
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

    fn one(dir: &Path) -> RunGroup {
        RunGroup {
            label: None,
            dirs: vec![dir.to_path_buf()],
        }
    }

    /// A history file of episodes at `steps`, each with this IoU.
    fn history(dir: &Path, episodes: &[(u32, f64)]) {
        let lines: String = episodes
            .iter()
            .map(|(steps, iou)| {
                format!("{{\"kind\":\"episode\",\"env_steps\":{steps},\"stats\":{{\"affordance_iou\":{iou}}}}}\n")
            })
            .collect();
        std::fs::write(dir.join(HISTORY_FILE), lines).unwrap();
    }

    #[test]
    fn long_runs_draw_at_most_max_dots_evenly_spaced() {
        let series: Series = (0..4_784).map(|i| (i as f64, 0.5)).collect();
        let dots: Vec<(f64, f64)> = thinned(&series, 1_000).collect();
        assert_eq!(dots.len(), 957, "every fifth of 4 784");
        assert_eq!(dots[0].0, 0.0);
        assert!(dots.windows(2).all(|pair| pair[1].0 - pair[0].0 == 5.0));
        let short: Series = (0..10).map(|i| (i as f64, 0.5)).collect();
        assert_eq!(
            thinned(&short, 1_000).count(),
            10,
            "short runs keep every dot"
        );
    }

    #[test]
    fn repeats_are_drawn_as_their_mean_within_their_range() {
        // Seed A reports 0.2 from step 100 to 1000; seed B 0.4, then 0.6
        // from step 500, from step 200 to 800.
        let a: Series = (1..=10).map(|i| (100.0 * i as f64, 0.2)).collect();
        let b: Series = (2..=8)
            .map(|i| (100.0 * i as f64, if i < 5 { 0.4 } else { 0.6 }))
            .collect();
        let curve = group_curve(&[a.clone(), b.clone()], 1, 9);
        // Steps 0, 100, …, 800 (the shorter run's end); 0 and 100 come
        // before seed B's first episode.
        let steps: Vec<f64> = curve.iter().map(|p| p.0).collect();
        assert_eq!(steps, [200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0]);
        for &(x, mean, lo, hi) in &curve {
            let b_value = if x < 500.0 { 0.4 } else { 0.6 };
            assert!(
                (mean - (0.2 + b_value) / 2.0).abs() < 1e-12,
                "{x}: mean {mean}"
            );
            assert_eq!((lo, hi), (0.2, b_value), "{x}");
        }
        assert!(group_curve(&[a, Series::new()], 1, 9).is_empty());

        // `--run-dir` values, the legend's names, and a plot with a group.
        let parsed: RunGroup = "ours=runs/x-seed1,runs/x-seed2".parse().unwrap();
        assert_eq!(parsed.label.as_deref(), Some("ours"));
        assert_eq!(parsed.dirs.len(), 2);
        assert!("runs/a,,runs/b".parse::<RunGroup>().is_err());
        let root = tempfile::tempdir().unwrap();
        let dirs: Vec<PathBuf> = ["ours64-seed1", "ours64-seed2", "nomap64"]
            .iter()
            .map(|n| root.path().join(n))
            .collect();
        for (dir, iou) in dirs.iter().zip([0.2, 0.4, 0.3]) {
            std::fs::create_dir(dir).unwrap();
            history(dir, &[(100, iou), (200, iou)]);
        }
        let seeds = RunGroup {
            label: None,
            dirs: dirs[..2].to_vec(),
        };
        assert_eq!(seeds.name(), "ours64 (2 runs)");
        let svg = root.path().join("seeds.svg");
        assert_eq!(plot(&[seeds, one(&dirs[2])], &svg, 5).unwrap(), 2);
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("ours64 (2 runs)") && text.contains("nomap64"));
        assert!(text.contains("<polygon"), "no band drawn for the repeats");
    }

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
        assert_eq!(plot(&[one(dir.path())], &svg, 5).unwrap(), 2);
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("<svg") && text.contains("affordance IoU"));
        for (_, title) in CURVES {
            assert!(text.contains(title), "no panel for {title}");
        }

        // Two runs: one line each, named in a legend.
        let other = tempfile::tempdir().unwrap();
        std::fs::write(
            other.path().join(HISTORY_FILE),
            "{\"kind\":\"episode\",\"env_steps\":300,\"stats\":{\"affordance_iou\":0.1}}\n",
        )
        .unwrap();
        assert_eq!(
            plot(&[one(dir.path()), one(other.path())], &svg, 5).unwrap(),
            2
        );
        let text = std::fs::read_to_string(&svg).unwrap();
        for run in [dir.path(), other.path()] {
            assert!(
                text.contains(&run_name(run)),
                "legend lacks {}",
                run_name(run)
            );
        }

        std::fs::write(dir.path().join(HISTORY_FILE), "").unwrap();
        assert!(plot(&[one(dir.path())], &svg, 5)
            .unwrap_err()
            .to_string()
            .contains("no episode records"));
    }
}
