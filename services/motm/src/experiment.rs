//! `motm experiment exp1|exp2|platforms|missions|generated|all`: the paper's experiments
//! in-process, trials spread over the available cores, with a progress bar, tables on stdout
//! and result files under `--out`.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use motm_sim::experiment::{Method, TrialResult, TrialSpec, TrialTrace, aggregate, plan};
use motm_sim::runner::RunnerConfig;

use crate::CliError;
use crate::{plots, report, trial};

/// Arguments of `motm experiment`.
#[derive(Args, Debug)]
pub struct ExperimentArgs {
    /// Which experiment: exp1, exp2, platforms, missions, generated (layouts drawn from each
    /// trial's seed, per robot) or all (every one but generated).
    pub which: String,
    /// Trials per table row.
    #[arg(long, default_value_t = 20)]
    pub trials: usize,
    /// Seed of the first trial of each row; trial k uses seed + k.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Folder for results.md, results.csv, results.json and the plots.
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Print the rows as JSON instead of the Markdown table.
    #[arg(long)]
    pub json: bool,
    /// Worker threads (default: the available cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Controller gains (TOML; default: `controllers.toml` in the config folder, the file the
    /// deployed stack reads).
    #[arg(long)]
    pub controllers: Option<PathBuf>,
}

/// One finished trial: its spec, its result, and its trace when one was recorded.
type Finished = (TrialSpec, TrialResult, Option<TrialTrace>);

/// Runs `specs` on `jobs` worker threads, calling `progress` after each trial. A trial that
/// cannot start (bad scenario) aborts the whole run with its error.
pub fn run_all(
    config_dir: &Path,
    config: &RunnerConfig,
    specs: &[TrialSpec],
    jobs: usize,
    trace_wanted: impl Fn(&TrialSpec) -> bool + Sync,
    progress: impl Fn() + Sync,
) -> Result<Vec<Finished>, CliError> {
    let next = AtomicUsize::new(0);
    let slots: Mutex<Vec<Option<Finished>>> = Mutex::new(vec![None; specs.len()]);
    let first_error: Mutex<Option<CliError>> = Mutex::new(None);
    std::thread::scope(|scope| {
        for _ in 0..jobs.max(1) {
            scope.spawn(|| {
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    if index >= specs.len() || first_error.lock().unwrap().is_some() {
                        break;
                    }
                    let spec = &specs[index];
                    match trial::run_spec(config_dir, spec, config, trace_wanted(spec)) {
                        Ok((result, trace)) => {
                            slots.lock().unwrap()[index] = Some((spec.clone(), result, trace));
                        }
                        Err(e) => {
                            first_error.lock().unwrap().get_or_insert(e);
                        }
                    }
                    progress();
                }
            });
        }
    });
    if let Some(e) = first_error.into_inner().unwrap() {
        return Err(e);
    }
    Ok(slots.into_inner().unwrap().into_iter().flatten().collect())
}

/// `motm experiment`.
pub fn run(config_dir: &Path, args: &ExperimentArgs) -> Result<(), CliError> {
    if args.trials == 0 {
        return Err(CliError::BadInput("--trials must be at least 1".into()));
    }
    let specs = plan(&args.which, args.trials, args.seed).map_err(CliError::BadInput)?;
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let bar = ProgressBar::new(specs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} trials, {elapsed} (eta {eta})")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.set_message(format!("motm experiment {}", args.which));
    // One trajectory trace per method: the first exp1 static trial at 0.3 m/s (or the first
    // trial of the method when exp1 is not part of the run).
    let traced: Vec<usize> = Method::ALL
        .iter()
        .filter_map(|&m| {
            specs
                .iter()
                .position(|s| s.method == m && s.experiment == "exp1" && s.base_speed == 0.3)
                .or_else(|| specs.iter().position(|s| s.method == m))
        })
        .collect();
    let config = trial::runner_config(config_dir, args.controllers.as_deref())?;
    let finished = run_all(
        config_dir,
        &config,
        &specs,
        jobs,
        |spec| traced.iter().any(|&i| specs[i] == *spec),
        || bar.inc(1),
    )?;
    bar.finish();
    let pairs: Vec<(TrialSpec, TrialResult)> = finished
        .iter()
        .map(|(spec, result, _)| (spec.clone(), result.clone()))
        .collect();
    let rows = aggregate(&pairs);
    let filter = finished
        .first()
        .map(|(_, r, _)| r.ee_acc_filter.clone())
        .unwrap_or_default();
    report::write_results(&args.out, &rows, &filter).map_err(CliError::Failed)?;
    let mut traces: Vec<(Method, TrialTrace)> = finished
        .into_iter()
        .filter_map(|(spec, _, trace)| trace.map(|t| (spec.method, t)))
        .collect();
    traces.sort_by_key(|(m, _)| Method::ALL.iter().position(|x| x == m));
    plots::platforms(&args.out, &rows).map_err(CliError::Failed)?;
    plots::trajectories(&args.out, &traces).map_err(CliError::Failed)?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).map_err(|e| CliError::Failed(e.to_string()))?
        );
    } else {
        print!("{}", report::markdown(&rows, &filter));
        motm_bus::say!("results written to {}", args.out.display());
    }
    Ok(())
}
