//! Plots of `motm experiment`, drawn with `plotters` once per backend (SVG and PNG):
//! - `platforms.{svg,png}`: task time and mean EE acceleration against base speed, per robot;
//! - `trajectories.{svg,png}`: top-down base and EE paths of one trial per method.

use std::path::Path;
use std::sync::Once;

use motm_sim::experiment::{Method, TableRow, TrialTrace};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

/// DejaVu Sans (Bitstream Vera licence, see `assets/DejaVuSans-LICENSE.txt`), so text renders
/// into PNGs without system fonts.
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// Registers the embedded font once per process.
fn ensure_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // The only failure is a malformed font, which the include above rules out.
        let _ = register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Plot size in pixels.
const SIZE: (u32, u32) = (1200, 520);

/// Series colours, one per robot or method.
const COLOURS: [RGBColor; 3] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
];

/// A drawing routine generic over the backend.
trait Figure {
    /// Draws the figure onto `root`.
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>;
}

/// Writes one figure as SVG and PNG.
fn write_figure(dir: &Path, stem: &str, figure: &impl Figure) -> Result<(), String> {
    ensure_font();
    let svg = dir.join(format!("{stem}.svg"));
    {
        let root = SVGBackend::new(&svg, SIZE).into_drawing_area();
        figure.draw(&root)?;
        root.present()
            .map_err(|e| format!("{}: {e}", svg.display()))?;
    }
    let png = dir.join(format!("{stem}.png"));
    let root = BitMapBackend::new(&png, SIZE).into_drawing_area();
    figure.draw(&root)?;
    root.present()
        .map_err(|e| format!("{}: {e}", png.display()))
}

/// Maps any plotters error to a string.
fn err<E: std::fmt::Debug>(e: E) -> String {
    format!("plot: {e:?}")
}

/// A column of a table row to plot.
type Metric = fn(&TableRow) -> f64;

/// Task time and mean acceleration against base speed, one line per robot.
struct PlatformsFigure<'a> {
    rows: Vec<&'a TableRow>,
}

impl Figure for PlatformsFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let panels = root.split_evenly((1, 2));
        let mut robots: Vec<&str> = self.rows.iter().map(|r| r.robot.as_str()).collect();
        robots.dedup();
        let v_max = self.rows.iter().map(|r| r.base_speed).fold(0.0, f64::max) + 0.05;
        let metrics: [(&str, Metric); 2] = [
            ("task time (s)", |r| r.task_time_s),
            ("mean |a| of EE (m/s²)", |r| r.ee_acc_mean),
        ];
        for (panel, (label, metric)) in panels.iter().zip(metrics) {
            let y_max = self.rows.iter().map(|r| metric(r)).fold(0.0, f64::max) * 1.15 + 1e-3;
            let mut chart = ChartBuilder::on(panel)
                .caption(label, ("sans-serif", 22))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(55)
                .build_cartesian_2d(0.0..v_max, 0.0..y_max)
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("base speed (m/s)")
                .y_desc(label)
                .draw()
                .map_err(err)?;
            for (i, robot) in robots.iter().enumerate() {
                let colour = COLOURS[i % COLOURS.len()];
                let points: Vec<(f64, f64)> = self
                    .rows
                    .iter()
                    .filter(|r| r.robot == *robot && r.successes > 0)
                    .map(|r| (r.base_speed, metric(r)))
                    .collect();
                chart
                    .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
                    .map_err(err)?
                    .label(*robot)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                    });
                chart
                    .draw_series(
                        points
                            .into_iter()
                            .map(|p| Circle::new(p, 4, colour.filled())),
                    )
                    .map_err(err)?;
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err)?;
        }
        Ok(())
    }
}

/// Top-down paths of base and EE, one panel per method.
struct TrajectoryFigure<'a> {
    traces: &'a [(Method, TrialTrace)],
}

impl Figure for TrajectoryFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let panels = root.split_evenly((1, self.traces.len().max(1)));
        for (panel, (method, trace)) in panels.iter().zip(self.traces) {
            let all = trace
                .base
                .iter()
                .chain(&trace.ee)
                .chain(trace.objects.iter().flatten())
                .chain(&trace.containers);
            let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for &(x, y) in all {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
            if x0 > x1 {
                (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
            }
            let pad = 0.3;
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{method}: top-down paths"), ("sans-serif", 20))
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(45)
                .build_cartesian_2d((x0 - pad)..(x1 + pad), (y0 - pad)..(y1 + pad))
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("x (m)")
                .y_desc("y (m)")
                .draw()
                .map_err(err)?;
            let series = [
                ("base", &trace.base, COLOURS[0]),
                ("end effector", &trace.ee, COLOURS[1]),
            ];
            for (name, points, colour) in series {
                chart
                    .draw_series(LineSeries::new(
                        points.iter().copied(),
                        colour.stroke_width(2),
                    ))
                    .map_err(err)?
                    .label(name)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                    });
            }
            for object in &trace.objects {
                chart
                    .draw_series(LineSeries::new(
                        object.iter().copied(),
                        COLOURS[2].stroke_width(3),
                    ))
                    .map_err(err)?;
            }
            chart
                .draw_series(trace.containers.iter().map(|&c| {
                    Rectangle::new(
                        [(c.0 - 0.15, c.1 - 0.15), (c.0 + 0.15, c.1 + 0.15)],
                        BLACK.stroke_width(2),
                    )
                }))
                .map_err(err)?;
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err)?;
        }
        Ok(())
    }
}

/// Writes `platforms.{svg,png}` from the platforms rows (nothing when there are none).
pub fn platforms(dir: &Path, rows: &[TableRow]) -> Result<(), String> {
    let rows: Vec<&TableRow> = rows
        .iter()
        .filter(|r| r.experiment == "platforms")
        .collect();
    if rows.is_empty() {
        return Ok(());
    }
    write_figure(dir, "platforms", &PlatformsFigure { rows })
}

/// Writes `trajectories.{svg,png}` from one trace per method (nothing when there are none).
pub fn trajectories(dir: &Path, traces: &[(Method, TrialTrace)]) -> Result<(), String> {
    if traces.is_empty() {
        return Ok(());
    }
    write_figure(dir, "trajectories", &TrajectoryFigure { traces })
}

#[cfg(test)]
mod tests {
    use super::*;
    use motm_sim::experiment::ObjectMotion;

    #[test]
    fn both_plots_are_written_as_svg_and_png() {
        let dir = std::env::temp_dir().join(format!("motm-plots-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rows: Vec<TableRow> = [
            ("frankie", 0.2, 17.0),
            ("frankie", 0.3, 12.0),
            ("fetch", 0.2, 18.0),
        ]
        .into_iter()
        .map(|(robot, v, t)| TableRow {
            experiment: "platforms",
            scenario: format!("platforms-{robot}"),
            robot: robot.into(),
            method: Method::Motm,
            base_speed: v,
            object: ObjectMotion::Static,
            trials: 2,
            successes: 2,
            task_time_s: t,
            mtph: 3600.0 / t,
            ee_acc_mean: 0.2,
            ee_acc_max: 1.0,
            round_trip_s: 0.0,
            failures: vec![],
        })
        .collect();
        platforms(&dir, &rows).unwrap();
        let trace = TrialTrace {
            base: vec![(0.0, 0.0), (1.0, 0.1), (2.0, 0.3)],
            ee: vec![(0.6, 0.0), (1.6, 0.2), (2.6, 0.4)],
            objects: vec![vec![(2.0, 0.6), (2.05, 0.62)]],
            containers: vec![(3.6, 1.6)],
            cycles: Vec::new(),
            ..TrialTrace::default()
        };
        trajectories(
            &dir,
            &[(Method::Motm, trace.clone()), (Method::Reactive, trace)],
        )
        .unwrap();
        for stem in ["platforms", "trajectories"] {
            let svg = std::fs::read_to_string(dir.join(format!("{stem}.svg"))).unwrap();
            assert!(svg.contains("<svg"), "{stem}.svg");
            let png = std::fs::read(dir.join(format!("{stem}.png"))).unwrap();
            assert_eq!(&png[1..4], b"PNG", "{stem}.png");
            assert!(png.len() > 10_000, "{stem}.png is {} bytes", png.len());
        }
        let svg = std::fs::read_to_string(dir.join("platforms.svg")).unwrap();
        assert!(svg.contains("fetch") && svg.contains("frankie"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
