//! `dwslam experiment why-filter`: thesis ch. 4, "Visual SLAM: why filter?" — the preliminary
//! experiment (§4.3, Figure 4.3) and the Monte Carlo comparison of BA-SLAM and filter-SLAM in
//! the four settings of §4.6 (Figures 4.5–4.13), written as CSV, PNG and `summary.json`.
//!
//! The computations are in `sim::preliminary` and `sim::why_filter`; this module turns their
//! results into tables, figures and the summary with the headline numbers and the checks of
//! issue 5.

use crate::plot::{self, Figure, HeatMap, PALETTE, Series, Style};
use anyhow::{Context, Result};
use serde_json::{Value, json};
use sim::preliminary;
use sim::why_filter::{
    CellStats, MOTION_ESTIMATES, MotionCellStats, PipelineResult, SensorKind, Setting, TrialResult,
    TrialSpec, log_log_slope, motion_estimate_name, run_trials, summarize, summarize_motion,
    trial_specs,
};
use std::fmt::Write as _;
use std::path::Path;

/// The preliminary experiment's results.
pub struct Preliminary {
    /// `M = 1 … 36`.
    pub m_values: Vec<usize>,
    /// The `N` grid.
    pub n_values: Vec<usize>,
    /// The cells, row-major in `M`.
    pub cells: Vec<preliminary::Cell>,
    /// The doubling comparisons.
    pub doublings: Vec<preliminary::Doubling>,
}

/// Runs the preliminary experiment over `M = 1…36` and the `N` grid.
pub fn run_preliminary() -> Preliminary {
    let m_values: Vec<usize> = (1..=preliminary::FRAMES).collect();
    let n_values = preliminary::n_grid();
    let cells = preliminary::surfaces(&m_values, &n_values);
    let doublings = preliminary::doublings(&cells, &n_values);
    Preliminary {
        m_values,
        n_values,
        cells,
        doublings,
    }
}

/// Writes `preliminary.csv`, the two surfaces of Figure 4.3 and the doubling table; returns
/// the summary entry.
pub fn write_preliminary(p: &Preliminary, out: &Path) -> Result<Value> {
    let mut csv = String::from(
        "m,n,ln_det_translation,ln_det_rotation,entropy_translation_bits,entropy_rotation_bits\n",
    );
    for c in &p.cells {
        writeln!(
            csv,
            "{},{},{:.9},{:.9},{:.6},{:.6}",
            c.m,
            c.n,
            c.ln_det_translation,
            c.ln_det_rotation,
            c.entropy_translation,
            c.entropy_rotation
        )?;
    }
    write(out, "preliminary.csv", &csv)?;
    let mut csv = String::from(
        "m,n,gain_2n_translation,gain_2m_translation,gain_2n_rotation,gain_2m_rotation\n",
    );
    for d in &p.doublings {
        writeln!(
            csv,
            "{},{},{:.6},{:.6},{:.6},{:.6}",
            d.m,
            d.n,
            d.gain_n_translation,
            d.gain_m_translation,
            d.gain_n_rotation,
            d.gain_m_rotation
        )?;
    }
    write(out, "preliminary_doubling.csv", &csv)?;
    let xs: Vec<f64> = p.m_values.iter().map(|&m| m as f64).collect();
    let ys: Vec<f64> = p.n_values.iter().map(|&n| n as f64).collect();
    for (name, title, pick) in [
        (
            "fig4_3_rotation.png",
            "Fig. 4.3 (rotation): entropy reduction vs ⟨1, 12⟩",
            (|c: &preliminary::Cell| c.entropy_rotation) as fn(&preliminary::Cell) -> f64,
        ),
        (
            "fig4_3_translation.png",
            "Fig. 4.3 (translation): entropy reduction vs ⟨1, 12⟩",
            |c: &preliminary::Cell| c.entropy_translation,
        ),
    ] {
        // Rows are N, columns M.
        let mut values = vec![f64::NAN; xs.len() * ys.len()];
        for c in &p.cells {
            let col = p.m_values.iter().position(|&m| m == c.m).expect("grid");
            let row = p.n_values.iter().position(|&n| n == c.n).expect("grid");
            values[row * xs.len() + col] = pick(c);
        }
        plot::heatmap(
            &out.join(name),
            &HeatMap {
                title,
                x_label: "keyframes M",
                y_label: "points N",
                value_label: "entropy reduction (bits)",
                x_values: &xs,
                y_values: &ys,
                values: &values,
                annotate: false,
            },
        )?;
    }
    let wins = p.doublings.iter().filter(|d| d.points_win()).count();
    let min_margin = |f: fn(&preliminary::Doubling) -> f64| {
        p.doublings.iter().map(f).fold(f64::INFINITY, f64::min)
    };
    let get = |m: usize, n: usize| p.cells.iter().find(|c| c.m == m && c.n == n);
    let corner = get(36, 425).map(|c| (c.entropy_translation, c.entropy_rotation));
    Ok(json!({
        "grid_points_compared": p.doublings.len(),
        "points_beat_frames": wins,
        "points_beat_frames_everywhere": wins == p.doublings.len(),
        "min_margin_translation_bits": min_margin(|d| d.gain_n_translation - d.gain_m_translation),
        "min_margin_rotation_bits": min_margin(|d| d.gain_n_rotation - d.gain_m_rotation),
        "entropy_reduction_36_425": corner.map(|(t, r)| json!({"translation": t, "rotation": r})),
        "entropy_reduction_1_425": get(1, 425).map(|c| json!({"translation": c.entropy_translation, "rotation": c.entropy_rotation})),
        "entropy_reduction_36_12": get(36, 12).map(|c| json!({"translation": c.entropy_translation, "rotation": c.entropy_rotation})),
    }))
}

fn write(dir: &Path, name: &str, text: &str) -> Result<()> {
    let path = dir.join(name);
    std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))
}

/// Runs the Monte Carlo trials with a progress callback.
pub fn run_settings(
    settings: &[Setting],
    sensors: &[SensorKind],
    trials: usize,
    seed: u64,
    workers: usize,
    on_done: &(dyn Fn() + Sync),
) -> Vec<(TrialSpec, TrialResult)> {
    let specs = trial_specs(settings, sensors, trials, seed);
    run_trials(&specs, workers, on_done)
}

/// Writes the pose-prediction study of thesis §4.6.3 (Fig. 4.10): `motion_trials.csv`,
/// `motion_cells.csv`, `fig4_10_accuracy.png`, `fig4_10_cost.png`; returns the summary entry
/// and a table.
pub fn write_motion(
    results: &[(TrialSpec, [PipelineResult; 3])],
    out: &Path,
) -> Result<(Value, String)> {
    let names = MOTION_ESTIMATES.map(motion_estimate_name);
    let mut csv = String::from("m,n,trial");
    for name in names {
        write!(csv, ",{name}_ok,{name}_e0,{name}_e1,{name}_cost")?;
    }
    csv.push('\n');
    for (s, r) in results {
        write!(csv, "{},{},{}", s.m, s.n, s.trial)?;
        for p in r {
            match &p.error {
                Some(e) => write!(csv, ",1,{:.9},{:.9},{:.9}", e[0], e[1], p.cost_total)?,
                None => csv.push_str(",0,,,"),
            }
        }
        csv.push('\n');
    }
    write(out, "motion_trials.csv", &csv)?;
    let cells = summarize_motion(results);
    let mut csv = String::from("m,n");
    for name in names {
        write!(
            csv,
            ",{name}_successes,{name}_rmse,{name}_median_error,{name}_ms_per_prediction"
        )?;
    }
    csv.push('\n');
    let ms_per_prediction =
        |c: &MotionCellStats, k: usize| 1e3 * c.estimates[k].cost_total / c.m as f64;
    let mut table = String::from(
        "Fig. 4.10 — monocular filter, setting (i): the end pose predicted from the filter's map\n\
         ⟨M, N⟩      RMSE (mm): motion-only BA / Alg. 6 approx. / Alg. 6 exact    ms per prediction: same order\n",
    );
    for c in &cells {
        write!(csv, "{},{}", c.m, c.n)?;
        for (k, e) in c.estimates.iter().enumerate() {
            write!(
                csv,
                ",{},{:.9},{:.9},{:.6}",
                e.successes,
                e.rmse,
                e.median_error,
                ms_per_prediction(c, k)
            )?;
        }
        csv.push('\n');
        writeln!(
            table,
            "⟨{:>2}, {:>3}⟩   {:>8.2} {:>8.2} {:>8.2}      {:>9.3} {:>9.3} {:>9.3}",
            c.m,
            c.n,
            1e3 * c.estimates[0].rmse,
            1e3 * c.estimates[1].rmse,
            1e3 * c.estimates[2].rmse,
            ms_per_prediction(c, 0),
            ms_per_prediction(c, 1),
            ms_per_prediction(c, 2),
        )?;
    }
    write(out, "motion_cells.csv", &csv)?;
    let labels = ["motion-only BA", "Alg. 6 approximate", "Alg. 6 exact"];
    let m_values: Vec<usize> = {
        let mut v: Vec<usize> = cells.iter().map(|c| c.m).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let (m_lo, m_hi) = (m_values[0], *m_values.last().expect("cells"));
    let curve = |m: usize, f: &dyn Fn(&MotionCellStats) -> f64| -> Vec<(f64, f64)> {
        cells
            .iter()
            .filter(|c| c.m == m)
            .map(|c| (c.n as f64, f(c)))
            .filter(|(_, y)| y.is_finite())
            .collect()
    };
    let mut series = Vec::new();
    for (k, label) in labels.iter().enumerate() {
        for (m, style) in [(m_lo, Style::Line), (m_hi, Style::Dashed)] {
            if style == Style::Dashed && m_hi == m_lo {
                continue;
            }
            series.push(Series {
                label: format!("{label}, M = {m}"),
                points: curve(m, &|c| 1e3 * c.estimates[k].rmse),
                color: PALETTE[k],
                style,
            });
        }
    }
    plot::plot(
        &out.join("fig4_10_accuracy.png"),
        &Figure {
            title: "Fig. 4.10 (a): predicted end pose, monocular filter map, setting (i)",
            x_label: "points N",
            y_label: "RMSE of the predicted end pose (mm, eq. 4.28-4.29)",
            equal_aspect: false,
            log_y: true,
        },
        &series,
    )?;
    let series: Vec<Series> = labels
        .iter()
        .enumerate()
        .map(|(k, label)| Series {
            label: format!("{label}, M = {m_lo}"),
            points: curve(m_lo, &|c| ms_per_prediction(c, k)),
            color: PALETTE[k],
            style: Style::Line,
        })
        .collect();
    plot::plot(
        &out.join("fig4_10_cost.png"),
        &Figure {
            title: "Fig. 4.10 (b): CPU time of one pose prediction",
            x_label: "points N",
            y_label: "ms per prediction",
            equal_aspect: false,
            log_y: true,
        },
        &series,
    )?;
    // Headline numbers: per estimate, the RMSE relative to motion-only BA (geometric mean over
    // the cells) and the cost exponent in N (N ≥ 60, all M pooled per M and averaged).
    let mut estimates = serde_json::Map::new();
    for (k, name) in names.iter().enumerate() {
        let ratios: Vec<f64> = cells
            .iter()
            .map(|c| (c.estimates[k].rmse / c.estimates[0].rmse).ln())
            .filter(|x| x.is_finite())
            .collect();
        let exponent = mean(
            &m_values
                .iter()
                .map(|&m| {
                    log_log_slope(
                        &cells
                            .iter()
                            .filter(|c| c.m == m && c.n >= 60)
                            .map(|c| (c.n as f64, c.estimates[k].cost_total))
                            .collect::<Vec<_>>(),
                    )
                })
                .collect::<Vec<_>>(),
        );
        let better = cells
            .iter()
            .filter(|c| c.estimates[k].rmse < c.estimates[0].rmse)
            .count();
        writeln!(
            table,
            "{:<18} RMSE / motion-only BA (geometric mean over cells) {:.3}; lower RMSE than motion-only BA in {}/{} cells; cost exponent in N (N ≥ 60) {:.2}",
            labels[k],
            mean(&ratios).exp(),
            better,
            cells.len(),
            exponent
        )?;
        estimates.insert(
            (*name).into(),
            json!({
                "rmse_over_motion_only_ba": mean(&ratios).exp(),
                "cells_better_than_motion_only_ba": better,
                "cost_exponent_n": exponent,
            }),
        );
    }
    Ok((
        json!({ "setting": "i", "sensor": "mono", "estimates": estimates, "cells": cells }),
        table,
    ))
}

/// Fitted cost exponents of one (setting, sensor): per `M`, the slope of `ln cost` over
/// `ln N` for `N ≥ n_min`.
fn exponents(cells: &[&CellStats], n_min: usize, joint: bool, filter: bool) -> Vec<(usize, f64)> {
    let mut ms: Vec<usize> = cells.iter().map(|c| c.m).collect();
    ms.sort_unstable();
    ms.dedup();
    ms.into_iter()
        .map(|m| {
            let pts: Vec<(f64, f64)> = cells
                .iter()
                .filter(|c| c.m == m && c.n >= n_min)
                .map(|c| {
                    let s = if filter { &c.filter } else { &c.ba };
                    (c.n as f64, if joint { s.cost_joint } else { s.cost_total })
                })
                .collect();
            (
                m,
                if pts.len() >= 2 {
                    log_log_slope(&pts)
                } else {
                    f64::NAN
                },
            )
        })
        .collect()
}

fn mean(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() {
        f64::NAN
    } else {
        f.iter().sum::<f64>() / f.len() as f64
    }
}

/// Writes `trials.csv`, `cells.csv`, the figures and returns the per-(setting, sensor)
/// summary and the table text.
pub fn write_settings(
    results: &[(TrialSpec, TrialResult)],
    out: &Path,
) -> Result<(Value, String, Vec<CellStats>)> {
    let mut csv = String::from(
        "setting,sensor,m,n,trial,ba_ok,ba_e0,ba_e1,ba_e2,ba_cost_total,ba_cost_joint,filter_ok,filter_e0,filter_e1,filter_e2,filter_cost_total,filter_cost_joint\n",
    );
    for (s, r) in results {
        let e = |p: &sim::why_filter::PipelineResult| -> String {
            let mut v = p.error.clone().unwrap_or_default();
            v.resize(3, f64::NAN);
            format!(
                "{},{:.9},{:.9},{:.9},{:.6e},{:.6e}",
                p.error.is_some() as u8,
                v[0],
                v[1],
                v[2],
                p.cost_total,
                p.cost_joint
            )
        };
        writeln!(
            csv,
            "{},{},{},{},{},{},{}",
            s.setting.name(),
            s.sensor.name(),
            s.m,
            s.n,
            s.trial,
            e(&r.ba),
            e(&r.filter)
        )?;
    }
    write(out, "trials.csv", &csv)?;
    let cells = summarize(results);
    let mut csv = String::from(
        "setting,sensor,m,n,ba_successes,ba_failures,ba_rmse,ba_median_error,ba_entropy_bits,ba_cost_total,ba_cost_joint,filter_successes,filter_failures,filter_rmse,filter_median_error,filter_entropy_bits,filter_cost_total,filter_cost_joint\n",
    );
    for c in &cells {
        let p = |s: &sim::why_filter::PipelineStats| {
            format!(
                "{},{},{:.6e},{:.6e},{:.4},{:.6e},{:.6e}",
                s.successes,
                s.failures,
                s.rmse,
                s.median_error,
                s.entropy_reduction,
                s.cost_total,
                s.cost_joint
            )
        };
        writeln!(
            csv,
            "{},{},{},{},{},{}",
            c.setting,
            c.sensor,
            c.m,
            c.n,
            p(&c.ba),
            p(&c.filter)
        )?;
    }
    write(out, "cells.csv", &csv)?;

    let mut table = String::new();
    writeln!(
        table,
        "{:<4} {:<6} {:>3} {:>4} | {:>10} {:>10} {:>6} | {:>7} {:>7} | {:>9} {:>9} | {:>5}",
        "set",
        "sensor",
        "M",
        "N",
        "RMSE BA",
        "RMSE filt",
        "f/BA",
        "E BA",
        "E filt",
        "cost BA",
        "cost filt",
        "fails"
    )?;
    let mut per_group = serde_json::Map::new();
    let mut groups: Vec<(&str, &str)> = cells.iter().map(|c| (c.setting, c.sensor)).collect();
    groups.dedup();
    for (setting_name, sensor_name) in groups {
        let these: Vec<&CellStats> = cells
            .iter()
            .filter(|c| c.setting == setting_name && c.sensor == sensor_name)
            .collect();
        for c in &these {
            writeln!(
                table,
                "{:<4} {:<6} {:>3} {:>4} | {:>10.3e} {:>10.3e} {:>6.3} | {:>7.2} {:>7.2} | {:>9.2e} {:>9.2e} | {:>2}/{:<2}",
                c.setting,
                c.sensor,
                c.m,
                c.n,
                c.ba.rmse,
                c.filter.rmse,
                c.filter.rmse / c.ba.rmse,
                c.ba.entropy_reduction,
                c.filter.entropy_reduction,
                c.ba.cost_total,
                c.filter.cost_total,
                c.ba.failures,
                c.filter.failures
            )?;
        }
        let setting = Setting::parse(setting_name).expect("own name");
        let sensor = if sensor_name == "mono" {
            SensorKind::Mono
        } else {
            SensorKind::Stereo
        };
        group_figures(&these, setting, sensor, results, out)?;
        let exp = |n_min: usize, joint: bool, filter: bool| -> Value {
            let e = exponents(&these, n_min, joint, filter);
            json!({
                "per_m": e.iter().map(|(m, s)| json!({"m": m, "exponent": s})).collect::<Vec<_>>(),
                "mean": mean(&e.iter().map(|x| x.1).collect::<Vec<_>>()),
            })
        };
        let mean_exponent = |n_min: usize, joint: bool, filter: bool| {
            mean(
                &exponents(&these, n_min, joint, filter)
                    .iter()
                    .map(|x| x.1)
                    .collect::<Vec<_>>(),
            )
        };
        writeln!(
            table,
            "{setting_name:<4} {sensor_name:<6} cost exponent in N (joint updates, mean over M): \
             BA {:.2} (N ≥ 60) {:.2} (N ≥ 120); filter {:.2} (N ≥ 60) {:.2} (N ≥ 120)",
            mean_exponent(60, true, false),
            mean_exponent(120, true, false),
            mean_exponent(60, true, true),
            mean_exponent(120, true, true),
        )?;
        let ratios: Vec<f64> = these.iter().map(|c| c.filter.rmse / c.ba.rmse).collect();
        per_group.insert(
            format!("{setting_name}/{sensor_name}"),
            json!({
                "cells": these.iter().map(|c| json!({
                    "m": c.m, "n": c.n,
                    "ba_rmse": c.ba.rmse, "filter_rmse": c.filter.rmse,
                    "ba_median_error": c.ba.median_error, "filter_median_error": c.filter.median_error,
                    "filter_over_ba_rmse": c.filter.rmse / c.ba.rmse,
                    "ba_cost_total": c.ba.cost_total, "filter_cost_total": c.filter.cost_total,
                    "ba_cost_joint": c.ba.cost_joint, "filter_cost_joint": c.filter.cost_joint,
                    "ba_entropy_bits": c.ba.entropy_reduction, "filter_entropy_bits": c.filter.entropy_reduction,
                    "ba_failures": c.ba.failures, "filter_failures": c.filter.failures,
                    "trials": c.ba.successes + c.ba.failures,
                })).collect::<Vec<_>>(),
                "filter_over_ba_rmse": {
                    "min": ratios.iter().copied().fold(f64::INFINITY, f64::min),
                    "max": ratios.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                    "geometric_mean": mean(&ratios.iter().map(|r| r.ln()).collect::<Vec<_>>()).exp(),
                },
                "cost_exponent_in_n": {
                    "ba_joint_n_ge_60": exp(60, true, false),
                    "ba_total_n_ge_60": exp(60, false, false),
                    "filter_joint_n_ge_60": exp(60, true, true),
                    "filter_total_n_ge_60": exp(60, false, true),
                    "ba_joint_n_ge_120": exp(120, true, false),
                    "ba_total_n_ge_120": exp(120, false, false),
                    "filter_joint_n_ge_120": exp(120, true, true),
                    "filter_total_n_ge_120": exp(120, false, true),
                    "ba_joint_all_n": exp(0, true, false),
                    "filter_joint_all_n": exp(0, true, true),
                },
            }),
        );
    }
    doubling_figure(&cells, out)?;
    Ok((Value::Object(per_group), table, cells))
}

/// Figures of one (setting, sensor): entropy reduction and accuracy/cost heat maps (Fig. 4.6,
/// 4.7, 4.9, 4.12), RMSE and cost over `N` (Fig. 4.6 e–f, 4.11), error against cost
/// (Fig. 4.13) and the error distributions at `M_min` (Fig. 4.5).
fn group_figures(
    cells: &[&CellStats],
    setting: Setting,
    sensor: SensorKind,
    results: &[(TrialSpec, TrialResult)],
    out: &Path,
) -> Result<()> {
    let tag = format!("{}_{}", setting.name(), sensor.name());
    let ms: Vec<usize> = setting.m_grid().to_vec();
    let ns: Vec<usize> = sim::why_filter::N_GRID.to_vec();
    let xs: Vec<f64> = ms.iter().map(|&m| m as f64).collect();
    let ys: Vec<f64> = ns.iter().map(|&n| n as f64).collect();
    let find = |m: usize, n: usize| cells.iter().find(|c| c.m == m && c.n == n);
    for (pipeline, is_filter) in [("ba", false), ("filter", true)] {
        for (kind, label, value) in [
            (
                "entropy",
                "entropy reduction (bits)",
                (|s: &sim::why_filter::PipelineStats| s.entropy_reduction)
                    as fn(&sim::why_filter::PipelineStats) -> f64,
            ),
            (
                "bps",
                "entropy reduction per second of joint updates (bits/s)",
                |s| s.entropy_reduction / s.cost_joint,
            ),
        ] {
            let mut values = vec![f64::NAN; xs.len() * ys.len()];
            for (r, &n) in ns.iter().enumerate() {
                for (c, &m) in ms.iter().enumerate() {
                    if let Some(cell) = find(m, n) {
                        let s = if is_filter { &cell.filter } else { &cell.ba };
                        values[r * xs.len() + c] = value(s);
                    }
                }
            }
            let title = format!(
                "setting ({}) {} {}: {}",
                setting.name(),
                sensor.name(),
                if is_filter { "filter" } else { "BA" },
                label
            );
            plot::heatmap(
                &out.join(format!("{kind}_{tag}_{pipeline}.png")),
                &HeatMap {
                    title: &title,
                    x_label: "keyframes M",
                    y_label: "points N",
                    value_label: label,
                    x_values: &xs,
                    y_values: &ys,
                    values: &values,
                    annotate: true,
                },
            )?;
        }
    }
    // RMSE and cost over N, one colour per M; BA solid, filter dashed.
    let curves = |f: &dyn Fn(&CellStats, bool) -> (f64, f64)| -> Vec<Series> {
        let mut series = Vec::new();
        for (k, &m) in ms.iter().enumerate() {
            for (is_filter, style, name) in
                [(false, Style::Line, "BA"), (true, Style::Dashed, "filter")]
            {
                let mut pts: Vec<(f64, f64)> = cells
                    .iter()
                    .filter(|c| c.m == m)
                    .map(|c| f(c, is_filter))
                    .collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                series.push(Series {
                    label: format!("{name} M={m}"),
                    points: pts,
                    color: PALETTE[k % PALETTE.len()],
                    style,
                });
            }
        }
        series
    };
    let title = format!(
        "setting ({}) {}: RMSE of the end position",
        setting.name(),
        sensor.name()
    );
    plot::plot(
        &out.join(format!("rmse_{tag}.png")),
        &Figure {
            title: &title,
            x_label: "log2 N (points)",
            y_label: "RMSE (m)",
            equal_aspect: false,
            log_y: true,
        },
        &curves(&|c, f| {
            (
                (c.n as f64).log2(),
                if f { c.filter.rmse } else { c.ba.rmse },
            )
        }),
    )?;
    let title = format!(
        "setting ({}) {}: cost of the whole pipeline",
        setting.name(),
        sensor.name()
    );
    plot::plot(
        &out.join(format!("cost_{tag}.png")),
        &Figure {
            title: &title,
            x_label: "log2 N (points)",
            y_label: "time per trial (s)",
            equal_aspect: false,
            log_y: true,
        },
        &curves(&|c, f| {
            (
                (c.n as f64).log2(),
                if f {
                    c.filter.cost_total
                } else {
                    c.ba.cost_total
                },
            )
        }),
    )?;
    let title = format!(
        "setting ({}) {}: error vs cost (joint updates)",
        setting.name(),
        sensor.name()
    );
    plot::plot(
        &out.join(format!("error_vs_cost_{tag}.png")),
        &Figure {
            title: &title,
            x_label: "log10 cost of the joint updates (s)",
            y_label: "RMSE (m)",
            equal_aspect: false,
            log_y: true,
        },
        &curves(&|c, f| {
            let s = if f { &c.filter } else { &c.ba };
            (s.cost_joint.log10(), s.rmse)
        }),
    )?;
    // Error distributions (Fig. 4.5) at M_min for the smallest and a large N.
    let m = setting.m_min();
    let mut series = Vec::new();
    for (k, n) in [15usize, 240].into_iter().enumerate() {
        for (is_filter, name) in [(false, "BA"), (true, "filter")] {
            let pts: Vec<(f64, f64)> = results
                .iter()
                .filter(|(s, _)| s.setting == setting && s.sensor == sensor && s.m == m && s.n == n)
                .filter_map(|(_, r)| {
                    let e = if is_filter { &r.filter } else { &r.ba }.error.as_ref()?;
                    Some((e[0], e[1]))
                })
                .collect();
            series.push(Series {
                label: format!("{name} ⟨{m}, {n}⟩"),
                points: pts,
                color: PALETTE[2 * k + is_filter as usize],
                style: Style::Points,
            });
        }
    }
    let title = format!(
        "setting ({}) {}: end-position errors (first two components)",
        setting.name(),
        sensor.name()
    );
    plot::plot(
        &out.join(format!("errors_{tag}.png")),
        &Figure {
            title: &title,
            x_label: "Δt₁ (m)",
            y_label: "Δt₂ (m)",
            equal_aspect: true,
            log_y: false,
        },
        &series,
    )?;
    Ok(())
}

/// Figure 4.8: the entropy gained by doubling `M` and by doubling `N` in settings (i) and
/// (ii), BA, per sensor.
fn doubling_figure(cells: &[CellStats], out: &Path) -> Result<()> {
    let mut series = Vec::new();
    for (k, (setting, sensor)) in [
        ("i", "stereo"),
        ("i", "mono"),
        ("ii", "stereo"),
        ("ii", "mono"),
    ]
    .into_iter()
    .enumerate()
    {
        let get = |m: usize, n: usize| {
            cells
                .iter()
                .find(|c| c.setting == setting && c.sensor == sensor && c.m == m && c.n == n)
                .map(|c| c.ba.entropy_reduction)
        };
        let mut double_m = Vec::new();
        let mut double_n = Vec::new();
        for m in [1usize, 2, 4, 8] {
            let dm: Vec<f64> = sim::why_filter::N_GRID
                .iter()
                .filter_map(|&n| Some(get(2 * m, n)? - get(m, n)?))
                .collect();
            if !dm.is_empty() {
                double_m.push(((m as f64).log2(), mean(&dm)));
            }
        }
        for n in [15usize, 30, 60, 120] {
            let dn: Vec<f64> = [1usize, 2, 4, 8, 16]
                .iter()
                .filter_map(|&m| Some(get(m, 2 * n)? - get(m, n)?))
                .collect();
            if !dn.is_empty() {
                double_n.push(((n as f64).log2(), mean(&dn)));
            }
        }
        let style = if setting == "i" {
            Style::Line
        } else {
            Style::Dashed
        };
        series.push(Series {
            label: format!("({setting}) {sensor}: M → 2M (x = log2 M)"),
            points: double_m,
            color: PALETTE[k],
            style,
        });
        series.push(Series {
            label: format!("({setting}) {sensor}: N → 2N (x = log2 N)"),
            points: double_n,
            color: PALETTE[(k + 4) % PALETTE.len()],
            style,
        });
    }
    if series.iter().all(|s| s.points.is_empty()) {
        return Ok(());
    }
    plot::plot(
        &out.join("fig4_8_doubling.png"),
        &Figure {
            title: "Fig. 4.8: entropy gained by doubling M or N (BA, mean over the other)",
            x_label: "log2 M or log2 N",
            y_label: "entropy reduction (bits)",
            equal_aspect: false,
            log_y: false,
        },
        &series,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_experiment_writes_everything_and_is_deterministic() {
        let dir = std::env::temp_dir().join(format!("dwslam-why-filter-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // A few small cells of two settings, both sensors, two trials each.
        let specs: Vec<TrialSpec> = trial_specs(
            &[Setting::I, Setting::IV],
            &[SensorKind::Stereo, SensorKind::Mono],
            2,
            7,
        )
        .into_iter()
        .filter(|s| s.m == s.setting.m_min() && s.n <= 30)
        .collect();
        assert_eq!(specs.len(), 2 * 2 * 2 * 2);
        let run = || run_trials(&specs, 2, &|| {});
        let a = run();
        let b = run();
        // Same seed, same numbers (costs are timings and may differ).
        assert_eq!(a.len(), b.len());
        for ((sa, ra), (sb, rb)) in a.iter().zip(&b) {
            assert_eq!(sa, sb);
            assert_eq!(ra.ba.error, rb.ba.error);
            assert_eq!(ra.filter.error, rb.filter.error);
        }
        let (summary, table, _) = write_settings(&a, &dir).unwrap();
        assert!(summary.get("i/stereo").is_some() && summary.get("iv/mono").is_some());
        // A header, a row per cell and an exponent line per (setting, sensor).
        assert_eq!(table.lines().count(), 1 + 2 * 2 * 2 + 2 * 2);
        // Every trial of these easy cells succeeds with a centimetre-level error.
        for (_, r) in &a {
            for p in [&r.ba, &r.filter] {
                let e = p.error.as_ref().expect("no failure");
                assert!(e.iter().map(|x| x * x).sum::<f64>().sqrt() < 0.1, "{e:?}");
            }
        }
        for f in [
            "trials.csv",
            "cells.csv",
            "rmse_i_stereo.png",
            "entropy_iv_mono_filter.png",
        ] {
            assert!(dir.join(f).exists(), "{f} missing");
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
