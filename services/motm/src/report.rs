//! Result files of `motm experiment`: the Markdown table (with the paper's figures alongside),
//! CSV and JSON.

use std::fmt::Write as _;
use std::path::Path;

use motm_sim::experiment::{ObjectMotion, PAPER_EXP2_ROUND_TRIP, TableRow, paper_row};

/// The results as a Markdown document: one table per experiment, paper figures alongside.
pub fn markdown(rows: &[TableRow], filter_description: &str) -> String {
    let mut out = String::from("# motm experiment results\n\n");
    let _ = writeln!(
        out,
        "Simulated trials with the default (realistic) noise. EE acceleration: {filter_description}.\n"
    );
    for experiment in ["exp1", "exp2", "platforms", "missions", "generated"] {
        let selected: Vec<&TableRow> = rows.iter().filter(|r| r.experiment == experiment).collect();
        if selected.is_empty() {
            continue;
        }
        let _ = writeln!(out, "## {}\n", title(experiment));
        out.push_str(
            "| robot | method | v (m/s) | object | sr | t (s) | MTPH | mean \\|a\\| | max \\|a\\| | round trip (s) | paper t | paper sr | paper MTPH | paper mean \\|a\\| | paper max \\|a\\| | failures |\n",
        );
        out.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
        for row in selected {
            let paper = paper_columns(row);
            let failures = row
                .failures
                .iter()
                .map(|(reason, n)| format!("{reason} ×{n}"))
                .collect::<Vec<_>>()
                .join(", ");
            let _ = writeln!(
                out,
                "| {} | {} | {:.1} | {} | {}/{} | {:.2} | {:.1} | {:.2} | {:.2} | {} | {} | {} |",
                if row.experiment == "missions" {
                    format!("{} ({})", row.robot, row.scenario)
                } else {
                    row.robot.clone()
                },
                row.method,
                row.base_speed,
                row.object.name(),
                row.successes,
                row.trials,
                row.task_time_s,
                row.mtph,
                row.ee_acc_mean,
                row.ee_acc_max,
                if matches!(row.experiment, "exp2" | "missions" | "generated") {
                    format!("{:.1}", row.round_trip_s)
                } else {
                    "–".into()
                },
                paper,
                if failures.is_empty() {
                    "–".into()
                } else {
                    failures
                },
            );
        }
        out.push('\n');
    }
    out
}

/// Human title of an experiment.
fn title(experiment: &str) -> &'static str {
    match experiment {
        "exp1" => "Exp 1: pick and place over about 4 m (paper Table I)",
        "exp2" => "Exp 2: ten objects in a row, each placed 3 m away",
        "missions" => {
            "Mission library: multi-task layouts (round trip: mean time per pick and place)"
        }
        "generated" => {
            "Generated layouts: 2-4 picks and places (and a press), one layout per seed, 2 m apart"
        }
        _ => "Platforms: task time and acceleration against base speed",
    }
}

/// The paper's figures for a row as five Markdown cells (dashes where it published none).
fn paper_columns(row: &TableRow) -> String {
    if row.experiment == "exp2" {
        let published = PAPER_EXP2_ROUND_TRIP
            .iter()
            .find(|(m, v, _)| *m == row.method && (v - row.base_speed).abs() < 1e-9);
        return match published {
            Some((_, _, t)) => format!("{t:.1} (round trip) | – | – | – | –"),
            None => "– | – | – | – | –".into(),
        };
    }
    match (row.experiment, paper_row(row.method, row.base_speed)) {
        ("exp1", Some(p)) => match row.object {
            ObjectMotion::Static => format!(
                "{:.2} | {}/10 | {:.1} | {:.2} | {:.2}",
                p.task_time_s, p.successes, p.mtph, p.ee_acc_mean, p.ee_acc_max
            ),
            ObjectMotion::Dynamic => format!(
                "{:.2} | {}/10 | – | – | –",
                p.dynamic_task_time_s, p.dynamic_successes
            ),
            ObjectMotion::Mixed => "– | – | – | – | –".into(),
        },
        _ => "– | – | – | – | –".into(),
    }
}

/// The rows as CSV, one line per row.
pub fn csv(rows: &[TableRow]) -> String {
    let mut out = String::from(
        "experiment,scenario,robot,method,base_speed,object,trials,successes,task_time_s,mtph,ee_acc_mean,ee_acc_max,round_trip_s,failures\n",
    );
    for row in rows {
        let failures = row
            .failures
            .iter()
            .map(|(reason, n)| format!("{reason}:{n}"))
            .collect::<Vec<_>>()
            .join(";");
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{:.4},{:.2},{:.4},{:.4},{:.4},{}",
            row.experiment,
            row.scenario,
            row.robot,
            row.method,
            row.base_speed,
            row.object.name(),
            row.trials,
            row.successes,
            row.task_time_s,
            row.mtph,
            row.ee_acc_mean,
            row.ee_acc_max,
            row.round_trip_s,
            failures
        );
    }
    out
}

/// Writes `results.md`, `results.csv` and `results.json` into `dir`.
pub fn write_results(
    dir: &Path,
    rows: &[TableRow],
    filter_description: &str,
) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let json = serde_json::to_string_pretty(rows).map_err(|e| e.to_string())?;
    for (name, text) in [
        ("results.md", markdown(rows, filter_description)),
        ("results.csv", csv(rows)),
        ("results.json", json),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_sim::experiment::Method;

    fn row(experiment: &'static str, method: Method, speed: f64) -> TableRow {
        TableRow {
            experiment,
            scenario: "exp1-static".into(),
            robot: "frankie".into(),
            method,
            base_speed: speed,
            object: ObjectMotion::Static,
            trials: 20,
            successes: 19,
            task_time_s: 12.5,
            mtph: 273.6,
            ee_acc_mean: 0.3,
            ee_acc_max: 1.1,
            round_trip_s: 0.0,
            failures: vec![("missed_grasp".into(), 1)],
        }
    }

    #[test]
    fn markdown_puts_paper_figures_beside_ours() {
        let md = markdown(&[row("exp1", Method::Motm, 0.3)], "filter");
        assert!(
            md.contains("| frankie | motm | 0.3 | static | 19/20 | 12.50 |"),
            "{md}"
        );
        assert!(md.contains("12.32 | 10/10 | 292.3"), "{md}");
        assert!(md.contains("missed_grasp ×1"));
    }

    #[test]
    fn csv_has_one_line_per_row_and_json_has_the_required_keys() {
        let rows = [
            row("exp1", Method::Motm, 0.3),
            row("exp2", Method::Reactive, 0.3),
        ];
        assert_eq!(csv(&rows).lines().count(), 3);
        let value = serde_json::to_value(&rows).unwrap();
        for key in [
            "method",
            "base_speed",
            "object",
            "trials",
            "successes",
            "task_time_s",
            "mtph",
            "ee_acc_mean",
            "ee_acc_max",
        ] {
            assert!(value[0].get(key).is_some(), "missing {key}");
        }
        assert_eq!(value[1]["method"], "reactive");
        assert_eq!(value[0]["object"], "static");
    }
}
