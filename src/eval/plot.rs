//! Line charts as PNG (plotters): training curves and the accuracy-vs-time study.
//!
//! Text needs a TrueType font. None is embedded (the repository stays lean); the first of
//! `$KPCN_FONT` and the usual Debian font paths that exists is used (`fonts-dejavu-core`,
//! which the set-up script installs). Without one, plotting fails with an error saying so.

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Fonts tried in order after `$KPCN_FONT`.
const FONT_PATHS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/truetype/freefont/FreeSans.ttf",
];

/// Errors of plotting.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// No usable font.
    #[error("no TrueType font for plot text — install fonts-dejavu-core or set KPCN_FONT=/path/to/font.ttf")]
    NoFont,
    /// Nothing to plot.
    #[error("{}: no finite, positive data to plot", path.display())]
    Empty {
        /// The plot file.
        path: PathBuf,
    },
    /// Drawing or writing failed.
    #[error("{}: cannot write the plot: {msg}", path.display())]
    Write {
        /// The plot file.
        path: PathBuf,
        /// Why.
        msg: String,
    },
}

/// One curve.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Points in drawing order.
    pub points: Vec<(f64, f64)>,
    /// Dashed (e.g. plain Monte Carlo, or validation curves).
    pub dashed: bool,
}

/// A chart: titles, axes and curves.
#[derive(Debug, Clone)]
pub struct Chart {
    /// Title above the plot.
    pub title: String,
    /// X axis label.
    pub x_label: String,
    /// Y axis label.
    pub y_label: String,
    /// Logarithmic x axis.
    pub log_x: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
    /// The curves.
    pub series: Vec<Series>,
}

fn register_font() -> Result<(), PlotError> {
    static FONT: OnceLock<bool> = OnceLock::new();
    let ok = *FONT.get_or_init(|| {
        let env = std::env::var_os("KPCN_FONT").map(PathBuf::from);
        let found = env.into_iter().chain(FONT_PATHS.iter().map(PathBuf::from)).find_map(|p| std::fs::read(p).ok());
        // plotters keeps fonts for the life of the process; one leaked file is that.
        found.is_some_and(|bytes| {
            plotters::style::register_font("sans-serif", FontStyle::Normal, Box::leak(bytes.into_boxed_slice())).is_ok()
        })
    });
    if ok { Ok(()) } else { Err(PlotError::NoFont) }
}

/// Colours for up to eight curves, then repeating.
const PALETTE: [RGBColor; 8] = [
    RGBColor(0, 0, 0),
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(120, 120, 120),
];

/// The data's range on one axis, padded; `None` when empty. Log axes skip values ≤ 0.
fn range(values: impl Iterator<Item = f64>, log: bool) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && (!log || *v > 0.0))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        return None;
    }
    Some(if log {
        let (lo, hi) = if lo == hi { (lo / 2.0, hi * 2.0) } else { (lo, hi) };
        (lo / 1.3, hi * 1.3)
    } else {
        let pad = if lo == hi { lo.abs().max(1.0) * 0.1 } else { (hi - lo) * 0.05 };
        (lo - pad, hi + pad)
    })
}

/// Draws `chart` into a `width`×`height` PNG at `path`.
pub fn write_png(chart: &Chart, path: &Path, width: u32, height: u32) -> Result<(), PlotError> {
    register_font()?;
    let err = |msg: String| PlotError::Write { path: path.into(), msg };
    let empty = || PlotError::Empty { path: path.into() };
    let xs = || chart.series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
    let ys = || chart.series.iter().flat_map(|s| s.points.iter().map(|p| p.1));
    let (x0, x1) = range(xs(), chart.log_x).ok_or_else(empty)?;
    let (y0, y1) = range(ys(), chart.log_y).ok_or_else(empty)?;
    let mut buf = vec![255u8; width as usize * height as usize * 3];
    let drawn = match (chart.log_x, chart.log_y) {
        (true, true) => draw(chart, &mut buf, (width, height), (x0..x1).log_scale(), (y0..y1).log_scale()),
        (true, false) => draw(chart, &mut buf, (width, height), (x0..x1).log_scale(), y0..y1),
        (false, true) => draw(chart, &mut buf, (width, height), x0..x1, (y0..y1).log_scale()),
        (false, false) => draw(chart, &mut buf, (width, height), x0..x1, y0..y1),
    };
    drawn.map_err(err)?;
    write_rgb_png(path, width as usize, height as usize, &buf).map_err(|e| err(e.to_string()))
}

fn draw<X, Y>(chart: &Chart, buf: &mut [u8], size: (u32, u32), x: X, y: Y) -> Result<(), String>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let root = BitMapBackend::with_buffer(buf, size).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut c = ChartBuilder::on(&root)
        .caption(&chart.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(70)
        .build_cartesian_2d(x, y)
        .map_err(|x| e(&x))?;
    c.configure_mesh()
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .label_style(("sans-serif", 13))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|x| e(&x))?;
    for (i, s) in chart.series.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        let style = colour.stroke_width(2);
        let pts: Vec<(f64, f64)> = s.points.iter().copied().filter(|(a, b)| a.is_finite() && b.is_finite()).collect();
        let series = if s.dashed {
            c.draw_series(DashedLineSeries::new(pts.clone(), 6, 4, style)).map_err(|x| e(&x))?
        } else {
            c.draw_series(LineSeries::new(pts.clone(), style)).map_err(|x| e(&x))?
        };
        series.label(&s.name).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        c.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled()))).map_err(|x| e(&x))?;
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 13))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))
}

/// Writes 8-bit RGB pixels (row-major, `width × height × 3`) as a PNG.
pub fn write_rgb_png(path: &Path, width: usize, height: usize, rgb: &[u8]) -> std::io::Result<()> {
    let file = std::fs::File::create(path)?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().map_err(std::io::Error::other)?;
    w.write_image_data(rgb).map_err(std::io::Error::other)?;
    w.finish().map_err(std::io::Error::other)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_log_chart_is_drawn_with_text_and_curves() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.png");
        let chart = Chart {
            title: "error vs time".into(),
            x_label: "seconds".into(),
            y_label: "relMSE".into(),
            log_x: true,
            log_y: true,
            series: vec![
                Series { name: "MC".into(), points: vec![(1.0, 1.0), (4.0, 0.25), (16.0, 0.0625)], dashed: true },
                Series { name: "kpcn".into(), points: vec![(1.5, 0.05), (4.5, 0.02)], dashed: false },
            ],
        };
        write_png(&chart, &path, 400, 300).unwrap();
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut px = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut px).unwrap();
        assert_eq!((reader.info().width, reader.info().height), (400, 300));
        // Curves in the palette's blue and black (text, axes) are both present.
        let has = |c: [u8; 3]| px.chunks_exact(3).any(|p| p == c);
        assert!(has([0, 114, 178]) && has([0, 0, 0]));
        let nothing = Chart { series: vec![], ..chart };
        assert!(matches!(write_png(&nothing, &path, 400, 300), Err(PlotError::Empty { .. })));
    }
}
