//! `--trace FILE.csv` and `--plot FILE.svg`: what the drives did over time.
//!
//! Every drive is sampled every [`SAMPLE_PERIOD_US`] and additionally whenever
//! its statusword or mode changes, so short states (a homing phase, a quick
//! stop) are not missed. The CSV is streamed as the drive runs; the plot is
//! drawn from the same samples on exit.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use plotters::prelude::*;

/// Regular sampling period of the trace.
pub const SAMPLE_PERIOD_US: u64 = 5_000;
/// Points per series above which the plot thins the samples out.
const PLOT_POINTS_MAX: usize = 20_000;
/// The plot's margin before the first and after the last motion: this
/// share of the motion's span, at least [`WINDOW_PAD_MIN_US`].
const WINDOW_PAD_SHARE: f64 = 0.05;
const WINDOW_PAD_MIN_US: u64 = 200_000;

pub const CSV_HEADER: &str = "time_s,address,position_steps,velocity_rpm,statusword,mode";

/// One observation of one drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sample {
    pub time_us: u64,
    pub drive: usize,
    pub address: u8,
    pub position_steps: i32,
    pub velocity_rpm: i32,
    pub statusword: u16,
    pub mode: i16,
}

impl Sample {
    fn csv_row(&self) -> String {
        format!(
            "{}.{:06},{},{},{},0x{:04X},{}",
            self.time_us / 1_000_000,
            self.time_us % 1_000_000,
            self.address,
            self.position_steps,
            self.velocity_rpm,
            self.statusword,
            self.mode
        )
    }
}

pub struct Trace {
    csv: Option<(PathBuf, BufWriter<File>)>,
    plot: Option<PathBuf>,
    /// Kept only when a plot is wanted.
    samples: Vec<Sample>,
    /// Per drive: time of the last regular sample, last statusword and mode.
    last: Vec<Option<(u64, u16, i16)>>,
}

impl Trace {
    /// Creates both files now, so a path that cannot be written is
    /// reported at start-up, not after the session; the message names the
    /// flag.
    pub fn new(csv: Option<&Path>, plot: Option<&Path>, drives: usize) -> Result<Self, String> {
        let csv = match csv {
            Some(p) => {
                let open = || -> io::Result<BufWriter<File>> {
                    let mut w = BufWriter::new(File::create(p)?);
                    writeln!(w, "{CSV_HEADER}")?;
                    Ok(w)
                };
                let w = open().map_err(|e| format!("--trace {}: {e}", p.display()))?;
                Some((p.to_path_buf(), w))
            }
            None => None,
        };
        if let Some(p) = plot {
            File::create(p).map_err(|e| format!("--plot {}: {e}", p.display()))?;
        }
        Ok(Self {
            csv,
            plot: plot.map(Path::to_path_buf),
            samples: Vec::new(),
            last: vec![None; drives],
        })
    }

    pub fn is_active(&self) -> bool {
        self.csv.is_some() || self.plot.is_some()
    }

    /// Offers a sample; it is recorded if the period has passed or the
    /// statusword or mode changed.
    pub fn offer(&mut self, s: Sample) -> io::Result<()> {
        if !self.is_active() {
            return Ok(());
        }
        let due = match self.last[s.drive] {
            None => true,
            Some((t, sw, mode)) => {
                s.time_us.saturating_sub(t) >= SAMPLE_PERIOD_US
                    || sw != s.statusword
                    || mode != s.mode
            }
        };
        if !due {
            return Ok(());
        }
        self.last[s.drive] = Some((s.time_us, s.statusword, s.mode));
        if let Some((_, w)) = &mut self.csv {
            writeln!(w, "{}", s.csv_row())?;
        }
        if self.plot.is_some() {
            self.samples.push(s);
        }
        Ok(())
    }

    /// Flushes the CSV and draws the plot. Returns what was written.
    pub fn finish(&mut self) -> Result<Vec<PathBuf>, String> {
        let mut written = Vec::new();
        if let Some((p, w)) = &mut self.csv {
            w.flush()
                .map_err(|e| format!("trace {}: {e}", p.display()))?;
            written.push(p.clone());
        }
        if let Some(p) = &self.plot {
            plot(p, &self.samples).map_err(|e| format!("plot {}: {e}", p.display()))?;
            written.push(p.clone());
        }
        Ok(written)
    }
}

/// The time span the plot shows, µs: from a little before the first
/// sample in which any drive moves (velocity not 0, or position changed
/// since its previous sample) to a little after the last; the whole run
/// when nothing moved.
pub fn motion_window(samples: &[Sample]) -> (u64, u64) {
    let (Some(first), Some(last)) = (samples.first(), samples.last()) else {
        return (0, 1_000_000);
    };
    let drives = samples.iter().map(|s| s.drive + 1).max().unwrap_or(0);
    let mut previous: Vec<Option<&Sample>> = vec![None; drives];
    let mut span: Option<(u64, u64)> = None;
    for s in samples {
        let before = previous[s.drive];
        let moved =
            s.velocity_rpm != 0 || before.is_some_and(|b| b.position_steps != s.position_steps);
        if moved {
            // a position change began after the drive's previous sample
            let start = before.map_or(s.time_us, |b| b.time_us);
            span = Some(match span {
                None => (start, s.time_us),
                Some((a, _)) => (a.min(start), s.time_us),
            });
        }
        previous[s.drive] = Some(s);
    }
    let Some((a, b)) = span else {
        return (first.time_us, last.time_us);
    };
    let pad = (((b - a) as f64 * WINDOW_PAD_SHARE) as u64).max(WINDOW_PAD_MIN_US);
    (
        a.saturating_sub(pad).max(first.time_us),
        (b + pad).min(last.time_us),
    )
}

/// Position (top) and velocity (bottom) over time, one line per drive.
pub fn plot(path: &Path, samples: &[Sample]) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (1200, 800)).into_drawing_area();
    root.fill(&WHITE)?;
    let (top, bottom) = root.split_vertically(400);

    let mut drives: Vec<(usize, u8)> = samples.iter().map(|s| (s.drive, s.address)).collect();
    drives.sort_unstable();
    drives.dedup_by_key(|d| d.0);

    // the motion, not the idle minutes around it
    let (from_us, to_us) = motion_window(samples);
    let samples: Vec<Sample> = samples
        .iter()
        .filter(|s| (from_us..=to_us).contains(&s.time_us))
        .copied()
        .collect();
    let (t_start, t_end) = (from_us as f64 / 1e6, to_us as f64 / 1e6);
    let t_range = t_start..(t_end.max(t_start + 1e-3));

    type Pick = fn(&Sample) -> i32;
    let panels: [(&DrawingArea<SVGBackend, _>, &str, &str, Pick); 2] = [
        (&top, "actual position (0x6064)", "steps", |s| {
            s.position_steps
        }),
        (&bottom, "actual velocity (0x606C)", "r/min", |s| {
            s.velocity_rpm
        }),
    ];
    for (area, title, unit, pick) in panels {
        let (lo, hi) = samples
            .iter()
            .map(pick)
            .fold((0i32, 0i32), |(lo, hi), v| (lo.min(v), hi.max(v)));
        let margin = ((i64::from(hi) - i64::from(lo)) / 20).max(1) as f64;
        let y_range = (f64::from(lo) - margin)..(f64::from(hi) + margin);
        let mut chart = ChartBuilder::on(area)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(90)
            .build_cartesian_2d(t_range.clone(), y_range)?;
        chart
            .configure_mesh()
            .x_desc("time, s")
            .y_desc(unit)
            .draw()?;
        for (n, &(drive, address)) in drives.iter().enumerate() {
            let series: Vec<&Sample> = samples.iter().filter(|s| s.drive == drive).collect();
            let stride = series.len().div_ceil(PLOT_POINTS_MAX).max(1);
            let points = series
                .iter()
                .step_by(stride)
                .map(|s| (s.time_us as f64 / 1e6, f64::from(pick(s))));
            let color = Palette99::pick(n).stroke_width(2);
            chart
                .draw_series(LineSeries::new(points, color))?
                .label(format!("drive {address}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(time_us: u64, position_steps: i32, statusword: u16) -> Sample {
        Sample {
            time_us,
            drive: 0,
            address: 1,
            position_steps,
            velocity_rpm: 60,
            statusword,
            mode: 1,
        }
    }

    #[test]
    fn samples_are_kept_per_period_and_on_every_status_change() {
        let dir = std::env::temp_dir();
        let csv = dir.join(format!("modbus-drive-trace-{}.csv", std::process::id()));
        let svg = dir.join(format!("modbus-drive-trace-{}.svg", std::process::id()));
        let mut t = Trace::new(Some(&csv), Some(&svg), 1).unwrap();
        t.offer(sample(0, 0, 0x0237)).unwrap(); // first: kept
        t.offer(sample(1_000, 10, 0x0237)).unwrap(); // too soon: dropped
        t.offer(sample(2_000, 20, 0x1637)).unwrap(); // statusword changed: kept
        t.offer(sample(2_000 + SAMPLE_PERIOD_US, 30, 0x1637))
            .unwrap(); // period: kept
        t.finish().unwrap();
        let text = std::fs::read_to_string(&csv).unwrap();
        let rows: Vec<&str> = text.lines().collect();
        assert_eq!(
            rows,
            [
                CSV_HEADER,
                "0.000000,1,0,60,0x0237,1",
                "0.002000,1,20,60,0x1637,1",
                "0.007000,1,30,60,0x1637,1"
            ]
        );
        let svg_text = std::fs::read_to_string(&svg).unwrap();
        assert!(svg_text.starts_with("<svg"));
        assert!(svg_text.contains("actual position"));
        assert!(svg_text.contains("<polyline"));
        std::fs::remove_file(csv).unwrap();
        std::fs::remove_file(svg).unwrap();
    }

    #[test]
    fn the_plot_window_is_the_motion_with_a_margin() {
        let mut run: Vec<Sample> = (0..=600u64)
            .map(|i| {
                let mut s = sample(i * 100_000, 0, 0x0237); // 60 s, 0.1 s apart
                s.velocity_rpm = 0;
                s
            })
            .collect();
        // nothing moves: the whole run
        assert_eq!(motion_window(&run), (0, 60_000_000));
        // a move from 20 s to 22 s: the position changes from 20.1 s on
        // (so it began after 20.0 s), the velocity is 0 again at 22 s
        for s in &mut run[201..220] {
            s.position_steps = 10 * (s.time_us / 100_000 - 200) as i32;
            s.velocity_rpm = 60;
        }
        for s in &mut run[220..] {
            s.position_steps = 190;
        }
        assert_eq!(motion_window(&run), (19_800_000, 22_100_000));
        // another drive moving at 40 s widens it; the margin is 5 % of the
        // 20 s between the moves
        let mut other = sample(40_000_000, 5, 0x0237);
        other.drive = 1;
        run.push(other);
        run.sort_by_key(|s| s.time_us);
        assert_eq!(motion_window(&run), (19_000_000, 41_000_000));
        assert_eq!(motion_window(&[]), (0, 1_000_000));
    }

    #[test]
    fn an_empty_run_still_draws_a_plot() {
        let svg =
            std::env::temp_dir().join(format!("modbus-drive-empty-{}.svg", std::process::id()));
        plot(&svg, &[]).unwrap();
        assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
        std::fs::remove_file(svg).unwrap();
    }
}
