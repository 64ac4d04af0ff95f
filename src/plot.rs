//! Figures: a small description of charts (lines, points, bands, bars)
//! rendered by plotters to SVG, and the SVG rasterised to PNG by resvg.
//!
//! Text is drawn with the DejaVu Sans font compiled into the binary, so
//! figures render the same on a machine without any font configuration.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;
pub use plotters::style::RGBColor;

use crate::atomic;
use crate::error::{Error, Result};

/// Colours that stay distinct for the colour-blind (Okabe & Ito).
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(240, 228, 66),
    RGBColor(0, 0, 0),
];
pub const GREY: RGBColor = RGBColor(120, 120, 120);
pub const BLACK_: RGBColor = RGBColor(0, 0, 0);

const FONT: &str = "sans-serif";

fn init_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // the embedded fonts are valid TrueType; failure here is a build error
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular())
            .unwrap_or_else(|_| panic!("embedded DejaVu Sans is not a valid font"));
        plotters::style::register_font(FONT, FontStyle::Bold, dejavu::sans::bold())
            .unwrap_or_else(|_| panic!("embedded DejaVu Sans Bold is not a valid font"));
    });
}

/// How a series is drawn.
#[derive(Clone, Debug)]
pub enum Mark {
    Line {
        width: u32,
    },
    Dashed {
        width: u32,
    },
    Points {
        size: u32,
    },
    /// Filled band between `y` (lower) and `y2` (upper), with opacity.
    Band {
        opacity: f64,
    },
    /// Histogram bars: `x` holds bin edges (one more than `y`).
    Bars {
        opacity: f64,
    },
    /// A vertical line at each `x`.
    VLines {
        width: u32,
    },
    /// Filled rectangles of size `w` × `h`, lower-left corners at (`x`, `y`).
    Cells {
        w: f64,
        h: f64,
        opacity: f64,
    },
}

#[derive(Clone, Debug)]
pub struct Series {
    pub label: Option<String>,
    pub color: RGBColor,
    pub mark: Mark,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub y2: Vec<f64>,
}

impl Series {
    pub fn line(
        label: impl Into<Option<String>>,
        color: RGBColor,
        x: Vec<f64>,
        y: Vec<f64>,
    ) -> Self {
        Series { label: label.into(), color, mark: Mark::Line { width: 2 }, x, y, y2: vec![] }
    }
    pub fn dashed(
        label: impl Into<Option<String>>,
        color: RGBColor,
        x: Vec<f64>,
        y: Vec<f64>,
    ) -> Self {
        Series { label: label.into(), color, mark: Mark::Dashed { width: 2 }, x, y, y2: vec![] }
    }
    pub fn points(
        label: impl Into<Option<String>>,
        color: RGBColor,
        x: Vec<f64>,
        y: Vec<f64>,
    ) -> Self {
        Series { label: label.into(), color, mark: Mark::Points { size: 2 }, x, y, y2: vec![] }
    }
    pub fn band(
        label: impl Into<Option<String>>,
        color: RGBColor,
        x: Vec<f64>,
        lo: Vec<f64>,
        hi: Vec<f64>,
    ) -> Self {
        Series { label: label.into(), color, mark: Mark::Band { opacity: 0.25 }, x, y: lo, y2: hi }
    }
    pub fn bars(
        label: impl Into<Option<String>>,
        color: RGBColor,
        edges: Vec<f64>,
        heights: Vec<f64>,
    ) -> Self {
        Series {
            label: label.into(),
            color,
            mark: Mark::Bars { opacity: 0.5 },
            x: edges,
            y: heights,
            y2: vec![],
        }
    }
    /// Filled `w` × `h` cells with lower-left corners at (`x`, `y`).
    pub fn cells(
        label: impl Into<Option<String>>,
        color: RGBColor,
        x: Vec<f64>,
        y: Vec<f64>,
        (w, h): (f64, f64),
        opacity: f64,
    ) -> Self {
        Series { label: label.into(), color, mark: Mark::Cells { w, h, opacity }, x, y, y2: vec![] }
    }
    pub fn vlines(label: impl Into<Option<String>>, color: RGBColor, x: Vec<f64>) -> Self {
        Series {
            label: label.into(),
            color,
            mark: Mark::VLines { width: 2 },
            x,
            y: vec![],
            y2: vec![],
        }
    }
    pub fn with_width(mut self, w: u32) -> Self {
        match &mut self.mark {
            Mark::Line { width } | Mark::Dashed { width } | Mark::VLines { width } => *width = w,
            Mark::Points { size } => *size = w,
            _ => {}
        }
        self
    }
    pub fn with_opacity(mut self, o: f64) -> Self {
        if let Mark::Band { opacity } | Mark::Bars { opacity } = &mut self.mark {
            *opacity = o;
        }
        self
    }
}

/// One panel: axes with labels (units belong in the labels) and series.
#[derive(Clone, Debug, Default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Plot x on a log₁₀ axis (ticks still show the values).
    pub log_x: bool,
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
    pub legend: bool,
    /// Where the legend goes; upper left unless the data live there.
    pub legend_at: LegendAt,
    /// Small panels of a matrix (corner plot): fewer ticks, smaller text.
    pub compact: bool,
    /// Leave the panel blank (the upper triangle of a corner plot).
    pub blank: bool,
    /// No tick labels on the y axis (a density whose scale means nothing).
    pub hide_y_ticks: bool,
    /// Names for the rows y = 1, 2, … (a forest plot), in place of numbers.
    pub y_names: Option<Vec<String>>,
}

/// Legend placement.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum LegendAt {
    #[default]
    UpperLeft,
    UpperRight,
    LowerRight,
    /// The middle: the empty inside of a hysteresis loop.
    Middle,
}

impl Chart {
    pub fn new(
        title: impl Into<String>,
        x_label: impl Into<String>,
        y_label: impl Into<String>,
    ) -> Self {
        Chart {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            legend: true,
            ..Chart::default()
        }
    }
    pub fn blank() -> Self {
        Chart { blank: true, ..Chart::default() }
    }
    pub fn with(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }
}

/// Panels on a grid, `columns` wide; each panel `panel_size` pixels.
#[derive(Clone, Debug)]
pub struct Figure {
    pub panels: Vec<Chart>,
    pub columns: usize,
    pub panel_size: (u32, u32),
}

impl Figure {
    pub fn single(chart: Chart) -> Self {
        Figure { panels: vec![chart], columns: 1, panel_size: (800, 560) }
    }
    pub fn grid(panels: Vec<Chart>, columns: usize) -> Self {
        Figure { panels, columns: columns.max(1), panel_size: (560, 420) }
    }
    fn size(&self) -> (u32, u32) {
        let rows = self.panels.len().div_ceil(self.columns).max(1) as u32;
        let cols = self.columns.min(self.panels.len().max(1)) as u32;
        (self.panel_size.0 * cols, self.panel_size.1 * rows)
    }
}

/// Writes `<stem>.svg` and `<stem>.png`, each atomically.
pub fn save(figure: &Figure, stem: &Path) -> Result<()> {
    init_fonts();
    let (w, h) = figure.size();
    // appended, not `with_extension`: stems like `fig1_I0.5A` contain dots
    let with_ext = |ext: &str| {
        let mut name = stem.file_name().unwrap_or_default().to_os_string();
        name.push(ext);
        stem.with_file_name(name)
    };
    let svg_path = with_ext(".svg");
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, h)).into_drawing_area();
        render(figure, &root).map_err(|e| Error::output(&svg_path, e))?;
        root.present().map_err(|e| Error::output(&svg_path, e))?;
    }
    atomic::write(&svg_path, svg.as_bytes())?;

    let png_path = with_ext(".png");
    let png = rasterise(&svg).map_err(|e| Error::output(&png_path, e))?;
    atomic::write(&png_path, &png)
}

/// The PNG of an SVG drawn by [`save`], its text in the embedded DejaVu.
fn rasterise(svg: &str) -> std::result::Result<Vec<u8>, String> {
    static FONTS: std::sync::OnceLock<std::sync::Arc<resvg::usvg::fontdb::Database>> =
        std::sync::OnceLock::new();
    let fonts = FONTS.get_or_init(|| {
        let mut db = resvg::usvg::fontdb::Database::new();
        db.load_font_data(dejavu::sans::regular().to_vec());
        db.load_font_data(dejavu::sans::bold().to_vec());
        db.set_sans_serif_family("DejaVu Sans");
        std::sync::Arc::new(db)
    });
    let options = resvg::usvg::Options { fontdb: fonts.clone(), ..Default::default() };
    let tree = resvg::usvg::Tree::from_str(svg, &options).map_err(|e| e.to_string())?;
    let size = tree.size().to_int_size();
    let mut pixmap =
        resvg::tiny_skia::Pixmap::new(size.width(), size.height()).ok_or("empty figure")?;
    resvg::render(&tree, resvg::tiny_skia::Transform::default(), &mut pixmap.as_mut());
    // the figures are opaque (white background): RGB, a quarter smaller than RGBA
    let rgb: Vec<u8> = pixmap.data().chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, size.width(), size.height());
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(png::Compression::Default);
    encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
    writer.write_image_data(&rgb).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())?;
    Ok(out)
}

type DrawResult<DB> =
    std::result::Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

fn render<DB: DrawingBackend>(figure: &Figure, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let rows = figure.panels.len().div_ceil(figure.columns).max(1);
    let areas = root.split_evenly((rows, figure.columns.min(figure.panels.len().max(1))));
    for (chart, area) in figure.panels.iter().zip(areas) {
        draw_chart(chart, &area)?;
    }
    Ok(())
}

/// Tick labels that stay short: plain decimals in [1e-3, 1e5), else 1.2e6.
pub fn tick(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.1e}");
        s.replace(".0e", "e")
    } else {
        let digits = (3 - a.log10().floor() as i32).clamp(0, 4) as usize;
        let s = format!("{v:.digits$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    }
}

/// A tick label on an axis spanning `span`: as [`tick`], with enough
/// significant digits that neighbouring ticks on a narrow axis differ
/// (1.995e5, 2.005e5 rather than 2e5, 2e5).
pub fn tick_in(v: f64, span: f64) -> String {
    let a = v.abs();
    if a < span * 1e-9 {
        return "0".into(); // rounding residue of a tick at zero
    }
    if !(span > 0.0) {
        return tick(v);
    }
    // about seven ticks: the digit of the tick step must show
    let exp = a.log10().floor() as i32;
    let digits = (exp - (span / 7.0).log10().floor() as i32 + 1).clamp(1, 7);
    if digits <= 2 {
        return tick(v);
    }
    if !(-3..5).contains(&exp) {
        let s = format!("{:.*e}", (digits - 1) as usize, v);
        let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
        let m = if m.contains('.') { m.trim_end_matches('0').trim_end_matches('.') } else { m };
        format!("{m}e{e}")
    } else {
        let decimals = (digits - 1 - exp).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    }
}

/// `v` rounded to `digits` significant digits (for ticks of a log axis,
/// whose positions are not round numbers).
pub fn significant(v: f64, digits: i32) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(digits - 1 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}

fn finite_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(v), h.max(v)));
    (lo <= hi).then_some((lo, hi))
}

fn padded((lo, hi): (f64, f64), share: f64) -> (f64, f64) {
    let span = if hi > lo { hi - lo } else { lo.abs().max(1.0) };
    (lo - share * span, hi + share * span)
}

/// The plotted ranges of x (log₁₀ on a log axis) and y: as given, else the
/// data's with a little padding.
fn axis_ranges(chart: &Chart) -> ((f64, f64), (f64, f64)) {
    let tx = |x: f64| if chart.log_x { x.log10() } else { x };
    let xr = chart
        .x_range
        .map(|(a, b)| (tx(a), tx(b)))
        .or_else(|| finite_range(chart.series.iter().flat_map(|s| s.x.iter().map(|x| tx(*x)))))
        .map(|r| if chart.x_range.is_some() { r } else { padded(r, 0.02) })
        .unwrap_or((0.0, 1.0));
    let yr = chart
        .y_range
        .or_else(|| {
            finite_range(chart.series.iter().flat_map(|s| {
                s.y.iter()
                    .chain(&s.y2)
                    .copied()
                    .chain(matches!(s.mark, Mark::Bars { .. }).then_some(0.0))
            }))
            .map(|r| padded(r, 0.05))
        })
        .unwrap_or((0.0, 1.0));
    (xr, yr)
}

fn draw_chart<DB: DrawingBackend>(chart: &Chart, area: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
    if chart.blank {
        return Ok(());
    }
    let (caption, labels, descs, ticks, y_area, x_area, margin) =
        if chart.compact { (13, 11, 13, 4, 56, 40, 6) } else { (18, 13, 15, 7, 70, 44, 12) };
    // names on the y axis need room: about 7 px per character
    let y_area = chart.y_names.as_ref().map_or(y_area, |n| {
        y_area.max(12 + 7 * n.iter().map(|s| s.chars().count()).max().unwrap_or(0) as u32)
    });
    let tx = |x: f64| if chart.log_x { x.log10() } else { x };
    let (xr, yr) = axis_ranges(chart);
    let mut c = ChartBuilder::on(area)
        .caption(&chart.title, (FONT, caption).into_font().style(FontStyle::Bold))
        .margin(margin)
        .x_label_area_size(x_area)
        .y_label_area_size(y_area)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    let log_x = chart.log_x;
    let (x_span, y_span) = (xr.1 - xr.0, yr.1 - yr.0);
    let x_fmt = move |v: &f64| {
        if log_x {
            tick(significant(10f64.powf(*v), 2))
        } else {
            tick_in(*v, x_span)
        }
    };
    let names = chart.y_names.clone();
    let y_fmt = move |v: &f64| match &names {
        // a name at each whole row, nothing between rows
        Some(names) => {
            let row = v.round();
            if (v - row).abs() < 1e-6 && row >= 1.0 && (row as usize) <= names.len() {
                names[row as usize - 1].clone()
            } else {
                String::new()
            }
        }
        None => tick_in(*v, y_span),
    };
    c.configure_mesh()
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .label_style((FONT, labels))
        .axis_desc_style((FONT, descs))
        // compact panels are narrow: three x labels never run together
        .x_labels(if chart.compact { 3 } else { ticks })
        .y_labels(match (&chart.y_names, chart.hide_y_ticks) {
            // enough requested labels that the steps fall on whole rows
            (Some(names), _) => 2 * (names.len() + 1),
            (None, true) => 0,
            (None, false) => ticks,
        })
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()?;
    let mut labelled = false;
    for s in &chart.series {
        labelled |= draw_series(&mut c, s, &tx, yr)?;
    }
    if labelled && chart.legend {
        c.configure_series_labels()
            .label_font((FONT, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .position(match chart.legend_at {
                LegendAt::UpperLeft => SeriesLabelPosition::UpperLeft,
                LegendAt::UpperRight => SeriesLabelPosition::UpperRight,
                LegendAt::LowerRight => SeriesLabelPosition::LowerRight,
                LegendAt::Middle => SeriesLabelPosition::MiddleMiddle,
            })
            .draw()?;
    }
    Ok(())
}

type Plane<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// Draws one series on the plane; returns whether it has a legend entry.
fn draw_series<'a, DB: DrawingBackend + 'a>(
    c: &mut Plane<'a, DB>,
    s: &Series,
    tx: &dyn Fn(f64) -> f64,
    yr: (f64, f64),
) -> std::result::Result<bool, DrawingAreaErrorKind<DB::ErrorType>> {
    let color = s.color;
    let xs: Vec<f64> = s.x.iter().map(|x| tx(*x)).collect();
    let anno = match &s.mark {
        Mark::Line { width } => c.draw_series(LineSeries::new(
            xs.iter()
                .zip(&s.y)
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|(x, y)| (*x, *y)),
            color.stroke_width(*width),
        ))?,
        Mark::Dashed { width } => c.draw_series(DashedLineSeries::new(
            xs.iter()
                .zip(&s.y)
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|(x, y)| (*x, *y)),
            8,
            5,
            color.stroke_width(*width),
        ))?,
        Mark::Points { size } => c.draw_series(
            xs.iter()
                .zip(&s.y)
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|(x, y)| Circle::new((*x, *y), *size, color.filled())),
        )?,
        Mark::Band { opacity } => {
            let mut poly: Vec<(f64, f64)> = xs.iter().zip(&s.y2).map(|(x, y)| (*x, *y)).collect();
            poly.extend(xs.iter().zip(&s.y).rev().map(|(x, y)| (*x, *y)));
            poly.retain(|(x, y)| x.is_finite() && y.is_finite());
            c.draw_series(std::iter::once(Polygon::new(poly, color.mix(*opacity).filled())))?
        }
        Mark::Bars { opacity } => c.draw_series(xs.windows(2).zip(&s.y).map(|(e, h)| {
            Rectangle::new([(e[0], 0.0), (e[1], *h)], color.mix(*opacity).filled())
        }))?,
        Mark::VLines { width } => {
            c.draw_series(xs.iter().map(|x| {
                PathElement::new(vec![(*x, yr.0), (*x, yr.1)], color.stroke_width(*width))
            }))?
        }
        Mark::Cells { w, h, opacity } => c.draw_series(xs.iter().zip(&s.y).map(|(x, y)| {
            Rectangle::new([(*x, *y), (*x + w, *y + h)], color.mix(*opacity).filled())
        }))?,
    };
    if let Some(label) = &s.label {
        let mark = s.mark.clone();
        anno.label(label).legend(move |(x, y)| match mark {
            Mark::Points { .. } => Circle::new((x + 10, y), 4, color.filled()).into_dyn(),
            Mark::Band { opacity } | Mark::Bars { opacity } | Mark::Cells { opacity, .. } => {
                Rectangle::new([(x, y - 5), (x + 20, y + 5)], color.mix(opacity.max(0.3)).filled())
                    .into_dyn()
            }
            _ => PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)).into_dyn(),
        });
    }
    Ok(s.label.is_some())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_short() {
        assert_eq!(tick(0.0), "0");
        assert_eq!(tick(2500.0), "2500");
        assert_eq!(tick(0.25), "0.25");
        assert_eq!(tick(150000.0), "1.5e5");
        assert_eq!(tick(-3.0e-5), "-3e-5");
        assert_eq!(tick(significant(3.981, 2)), "4");
        assert_eq!(tick(significant(15.85, 2)), "16");
        assert_eq!(tick(significant(0.006310, 2)), "0.0063");
        // narrow axes keep neighbouring ticks apart
        assert_eq!(tick_in(199_500.0, 2000.0), "1.995e5");
        assert_eq!(tick_in(1.198, 0.01), "1.198");
        assert_eq!(tick_in(0.00021, 2e-5), "2.1e-4");
        assert_eq!(tick_in(2500.0, 5000.0), "2500");
    }

    #[test]
    fn figure_renders_to_svg_and_png() {
        let dir = tempfile::tempdir().unwrap();
        let chart = Chart::new("t", "x (m)", "y (N)")
            .with(Series::line(Some("line".into()), PALETTE[0], vec![0.0, 1.0], vec![0.0, 2.0]))
            .with(Series::band(
                Some("band".into()),
                PALETTE[1],
                vec![0.0, 1.0],
                vec![-1.0, 0.0],
                vec![1.0, 3.0],
            ));
        save(&Figure::single(chart), &dir.path().join("f")).unwrap();
        let svg = std::fs::read_to_string(dir.path().join("f.svg")).unwrap();
        assert!(svg.contains("<svg") && svg.contains("x (m)"));
        let png = std::fs::read(dir.path().join("f.png")).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}
