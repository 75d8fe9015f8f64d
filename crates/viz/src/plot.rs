//! Curves (plotters bitmap backend into a buffer, PNG-encoded with `image`) and depth pictures
//! (colorous turbo colour map, radar overlays, error maps).
//!
//! Text needs a TrueType font: plotters' `ab_glyph` backend has none built in, so DejaVu Sans
//! (the `dejavu` crate's copy of DejaVu 2.37) is compiled into the binary and registered once:
//! every machine draws the same labels, with or without system fonts.

use std::sync::OnceLock;

use plotters::prelude::*;

use crate::VizError;

/// Register the embedded font with plotters once; true when text can be drawn (false only if
/// the embedded font failed to parse, which the tests rule out; the pictures then go without
/// text rather than failing).
pub fn fonts_available() -> bool {
    static OK: OnceLock<bool> = OnceLock::new();
    *OK.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
            .is_ok()
    })
}

type Series<'a> = (&'a str, &'a [(u64, f64)]);

const COLOURS: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
];

fn plot_err<E: std::fmt::Debug>(e: E) -> VizError {
    VizError::Plot(format!("{e:?}"))
}

/// A plotters drawing area on a bitmap buffer.
type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// A chart with f64 axes on a bitmap buffer.
type Chart<'a, 'b> = ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// A chart builder on `area` with `margin` px margins: with `text`, the caption `title`
/// (18 pt) and label areas of `label_px` (x, y) px; without, 4 px label areas.
fn chart_builder<'a, 'b>(
    area: &'a Area<'b>,
    title: &str,
    text: bool,
    margin: u32,
    label_px: (u32, u32),
) -> ChartBuilder<'a, 'static, BitMapBackend<'b>> {
    let mut b = ChartBuilder::on(area);
    b.margin(margin);
    if text {
        b.caption(title, ("sans-serif", 18))
            .x_label_area_size(label_px.0)
            .y_label_area_size(label_px.1);
    } else {
        b.x_label_area_size(4).y_label_area_size(4);
    }
    b
}

/// Draw series `i` (colour `COLOURS[i]`, 2 px line) with dots at its points when `dots`;
/// with `text`, register its legend entry `name`.
fn draw_line(
    chart: &mut Chart<'_, '_>,
    i: usize,
    name: &str,
    data: Vec<(f64, f64)>,
    text: bool,
    dots: bool,
) -> Result<(), VizError> {
    let c = COLOURS[i % COLOURS.len()];
    let line = chart
        .draw_series(LineSeries::new(data.clone(), c.stroke_width(2)))
        .map_err(plot_err)?;
    if text && !name.is_empty() {
        line.label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c));
    }
    if dots {
        chart
            .draw_series(data.iter().map(|&p| Circle::new(p, 3, c.filled())))
            .map_err(plot_err)?;
    }
    Ok(())
}

/// The legend of the registered series (at `position`, plotters' default when `None`).
fn draw_legend<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    position: Option<SeriesLabelPosition>,
) -> Result<(), VizError> {
    let mut labels = chart.configure_series_labels();
    if let Some(p) = position {
        labels.position(p);
    }
    labels
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)
}

/// Axis ranges of a curves panel: x from 0 (or the first iteration) to at least 1 past it,
/// y over the finite values (0..1 when none, at least 1 tall) padded by 5 %.
fn curve_ranges(series: &[Series<'_>]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|(_, s)| s.iter().map(|&(x, y)| (x as f64, y)))
        .filter(|(_, y)| y.is_finite())
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (0.0f64, 1.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, y) in &pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !y0.is_finite() {
        y0 = 0.0;
        y1 = 1.0;
    }
    if y1 - y0 < 1e-9 {
        y1 = y0 + 1.0;
    }
    let pad = (y1 - y0) * 0.05;
    (x0..x1.max(x0 + 1.0), (y0 - pad)..(y1 + pad))
}

/// The iteration ticks of a curves panel over `xs`: at most 10, on whole iterations, so that
/// each tick label is an integer (`iteration_tick` prints them).
fn iteration_ticks(xs: &std::ops::Range<f64>) -> usize {
    ((xs.end - xs.start).round() as usize + 1).clamp(2, 10)
}

/// An iteration tick's label: the integer, or nothing between two iterations.
fn iteration_tick(x: &f64) -> String {
    if (x - x.round()).abs() < 1e-6 {
        format!("{}", x.round() as i64)
    } else {
        String::new()
    }
}

fn panel(
    area: &Area<'_>,
    title: &str,
    y_label: &str,
    series: &[Series<'_>],
    text: bool,
) -> Result<(), VizError> {
    let (xs, ys) = curve_ranges(series);
    let x_ticks = iteration_ticks(&xs);
    let mut chart = chart_builder(area, title, text, 12, (40, 60))
        .build_cartesian_2d(xs, ys)
        .map_err(plot_err)?;
    let mut mesh = chart.configure_mesh();
    if text {
        mesh.x_desc("iteration")
            .y_desc(y_label)
            .x_labels(x_ticks)
            .x_label_formatter(&iteration_tick);
    } else {
        mesh.disable_x_mesh()
            .disable_y_mesh()
            .x_labels(0)
            .y_labels(0);
    }
    mesh.draw().map_err(plot_err)?;
    for (i, (name, s)) in series.iter().enumerate() {
        let data: Vec<(f64, f64)> = s
            .iter()
            .filter(|(_, y)| y.is_finite())
            .map(|&(x, y)| (x as f64, y))
            .collect();
        let dots = data.len() < 60;
        draw_line(&mut chart, i, name, data, text, dots)?;
    }
    if text {
        draw_legend(&mut chart, None)?;
    }
    Ok(())
}

/// Two panels side by side (left: e.g. training loss; right: e.g. validation RMSE), PNG bytes.
pub fn curves_png(left: &[Series<'_>], right: &[Series<'_>]) -> Result<Vec<u8>, VizError> {
    curves_png_labelled(
        ("training loss", "loss", left),
        ("validation", "RMSE (m)", right),
    )
}

/// [`curves_png`] with each panel's (title, y-axis label, series).
pub fn curves_png_labelled(
    left: (&str, &str, &[Series<'_>]),
    right: (&str, &str, &[Series<'_>]),
) -> Result<Vec<u8>, VizError> {
    let (w, h) = (1200u32, 450u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    let text = fonts_available();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let (a, b) = root.split_horizontally(w / 2);
        panel(&a, left.0, left.1, left.2, text)?;
        panel(&b, right.0, right.1, right.2, text)?;
        root.present().map_err(plot_err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| VizError::BufferSize("plot"))?;
    encode_rgb(&img)
}

/// PNG-encode an RGB image.
pub fn encode_rgb(img: &image::RgbImage) -> Result<Vec<u8>, VizError> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(VizError::Png)?;
    Ok(out.into_inner())
}

/// Turbo colour map of a depth map: near = red, far = blue; 0 (no data) = black.
pub fn colorize_depth(depth_m: &[f32], w: u32, h: u32, max_m: f32) -> image::RgbImage {
    let lut: Vec<[u8; 3]> = (0..256)
        .map(|i| {
            let c = colorous::TURBO.eval_rational(255 - i, 256);
            [c.r, c.g, c.b]
        })
        .collect();
    let mut img = image::RgbImage::new(w, h);
    for (i, p) in img.pixels_mut().enumerate() {
        let d = depth_m.get(i).copied().unwrap_or(0.0);
        if d > 0.0 && d.is_finite() {
            let k = ((d / max_m).clamp(0.0, 1.0) * 255.0) as usize;
            p.0 = lut[k];
        }
    }
    img
}

/// The image with every pixel holding data in `points_m` drawn as a coloured dot (radius r).
pub fn overlay_points(
    base: &image::RgbImage,
    points_m: &[f32],
    max_m: f32,
    radius: i32,
) -> image::RgbImage {
    let (w, h) = base.dimensions();
    let mut out = base.clone();
    for (i, &d) in points_m.iter().enumerate() {
        if !(d > 0.0 && d.is_finite()) {
            continue;
        }
        let (u, v) = ((i as u32 % w) as i32, (i as u32 / w) as i32);
        let c = colorous::TURBO.eval_continuous(1.0 - (d / max_m).clamp(0.0, 1.0) as f64);
        for dv in -radius..=radius {
            for du in -radius..=radius {
                let (x, y) = (u + du, v + dv);
                if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h {
                    out.put_pixel(x as u32, y as u32, image::Rgb([c.r, c.g, c.b]));
                }
            }
        }
    }
    out
}

/// Absolute error |pred − gt| at GT pixels (dilated by 1 px for visibility), magma map
/// scaled to `max_err_m`; black elsewhere.
pub fn error_map(pred_m: &[f32], gt_m: &[f32], w: u32, h: u32, max_err_m: f32) -> image::RgbImage {
    let mut img = image::RgbImage::new(w, h);
    for (i, (&p, &g)) in pred_m.iter().zip(gt_m).enumerate() {
        if g > 0.0 {
            let e = ((p - g).abs() / max_err_m).clamp(0.0, 1.0) as f64;
            let c = colorous::INFERNO.eval_continuous(e);
            let (u, v) = (i as u32 % w, i as u32 / w);
            for (x, y) in [(u, v), (u + 1, v), (u, v + 1), (u + 1, v + 1)] {
                if x < w && y < h {
                    img.put_pixel(x, y, image::Rgb([c.r, c.g, c.b]));
                }
            }
        }
    }
    img
}

/// De-normalise a [3,H,W] image normalised with per-channel `mean` and `std` (SPEC §6: the
/// ImageNet statistics, `depthsense_data::IMAGENET_MEAN` / `IMAGENET_STD`) back to RGB8.
pub fn denormalise(chw: &[f32], w: u32, h: u32, mean: [f32; 3], std: [f32; 3]) -> image::RgbImage {
    let plane = (w * h) as usize;
    let mut img = image::RgbImage::new(w, h);
    for (i, p) in img.pixels_mut().enumerate() {
        for c in 0..3 {
            let x = chw[c * plane + i] * std[c] + mean[c];
            p.0[c] = (x.clamp(0.0, 1.0) * 255.0).round() as u8;
        }
    }
    img
}

/// One panel of [`bar_charts_png`]: bars with symmetric error bars.
#[derive(Debug, Clone, Copy)]
pub struct BarPanel<'a> {
    pub title: &'a str,
    pub labels: &'a [&'a str],
    pub means: &'a [f64],
    /// Half-length of each error bar (e.g. the sample std); non-finite = no error bar.
    pub stds: &'a [f64],
    pub y_label: &'a str,
}

/// Half-length of bar `i`'s error bar (0 when absent or not finite).
fn bar_err(p: &BarPanel<'_>, i: usize) -> f64 {
    p.stds
        .get(i)
        .copied()
        .filter(|s| s.is_finite())
        .unwrap_or(0.0)
}

/// Top of a bar panel's y axis: 12 % above the highest finite bar plus its error bar (1 when
/// there is none above 0).
fn bar_top(p: &BarPanel<'_>, n: usize) -> f64 {
    let mut y1 = 0.0f64;
    for i in 0..n {
        if p.means[i].is_finite() {
            y1 = y1.max(p.means[i] + bar_err(p, i).abs());
        }
    }
    if y1 <= 0.0 {
        y1 = 1.0;
    }
    y1 * 1.12
}

fn bar_panel(area: &Area<'_>, p: &BarPanel<'_>, text: bool) -> Result<(), VizError> {
    let n = p.labels.len().min(p.means.len());
    let y1 = bar_top(p, n);
    let mut chart = chart_builder(area, p.title, text, 14, (34, 56))
        .build_cartesian_2d(0.0f64..n.max(1) as f64, 0.0f64..y1)
        .map_err(plot_err)?;
    let mut mesh = chart.configure_mesh();
    mesh.disable_x_mesh().x_labels(0);
    if text {
        mesh.y_desc(p.y_label);
    } else {
        mesh.y_labels(0);
    }
    mesh.draw().map_err(plot_err)?;
    for i in 0..n {
        let m = p.means[i];
        if !m.is_finite() {
            continue;
        }
        let s = bar_err(p, i).abs();
        draw_bar(&mut chart, i, m, s)?;
        if text {
            // The value sits just above the error bar.
            let value_y = m + s + 0.015 * y1;
            draw_bar_text(area, &mut chart, p.labels[i], i, m, value_y)?;
        }
    }
    Ok(())
}

/// Bar `i` of height `m` (colour `COLOURS[i]`) with a ± `s` error bar (none when `s` is 0).
fn draw_bar(chart: &mut Chart<'_, '_>, i: usize, m: f64, s: f64) -> Result<(), VizError> {
    let c = COLOURS[i % COLOURS.len()];
    let (x0, x1) = (i as f64 + 0.15, i as f64 + 0.85);
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(x0, 0.0), (x1, m)],
            c.mix(0.8).filled(),
        )))
        .map_err(plot_err)?;
    if s > 0.0 {
        let xc = i as f64 + 0.5;
        let (lo, hi) = ((m - s).max(0.0), m + s);
        let style = BLACK.stroke_width(2);
        chart
            .draw_series([
                PathElement::new(vec![(xc, lo), (xc, hi)], style),
                PathElement::new(vec![(xc - 0.12, lo), (xc + 0.12, lo)], style),
                PathElement::new(vec![(xc - 0.12, hi), (xc + 0.12, hi)], style),
            ])
            .map_err(plot_err)?;
    }
    Ok(())
}

/// The label of bar `i` under it and its value `m` (3 decimals) at height `value_y`.
fn draw_bar_text(
    area: &Area<'_>,
    chart: &mut Chart<'_, '_>,
    label: &str,
    i: usize,
    m: f64,
    value_y: f64,
) -> Result<(), VizError> {
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    // Variant name under the bar (drawn on the panel: outside the plotting area).
    let (px, py) = chart.backend_coord(&(i as f64 + 0.5, 0.0));
    let base = area.get_base_pixel();
    let style = ("sans-serif", 15)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Center, VPos::Top));
    area.draw(&Text::new(
        label.to_string(),
        (px - base.0, py - base.1 + 6),
        style,
    ))
    .map_err(plot_err)?;
    let value_style = ("sans-serif", 13)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Center, VPos::Bottom));
    chart
        .draw_series(std::iter::once(Text::new(
            format!("{m:.3}"),
            (i as f64 + 0.5, value_y),
            value_style,
        )))
        .map_err(plot_err)?;
    Ok(())
}

/// Several bar charts side by side (one per panel), PNG bytes (500 px wide per panel).
pub fn bar_charts_png(panels: &[BarPanel<'_>]) -> Result<Vec<u8>, VizError> {
    panels_png(panels, 500, bar_panel)
}

/// `panels` side by side, `panel_w` px wide each and 420 px high, each drawn by `draw` (told
/// whether fonts are available), on white; PNG bytes.
fn panels_png<P>(
    panels: &[P],
    panel_w: u32,
    draw: impl Fn(
        &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
        &P,
        bool,
    ) -> Result<(), VizError>,
) -> Result<Vec<u8>, VizError> {
    let k = panels.len().max(1) as u32;
    let (w, h) = (panel_w * k, 420u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    let text = fonts_available();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let areas = root.split_evenly((1, k as usize));
        for (a, p) in areas.iter().zip(panels) {
            draw(a, p, text)?;
        }
        root.present().map_err(plot_err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| VizError::BufferSize("plot"))?;
    encode_rgb(&img)
}

/// A bar chart of `means` with ± `stds` error bars (non-finite std = no bar), PNG bytes.
pub fn bar_chart_png(
    title: &str,
    labels: &[&str],
    means: &[f64],
    stds: &[f64],
    y_label: &str,
) -> Result<Vec<u8>, VizError> {
    bar_charts_png(&[BarPanel {
        title,
        labels,
        means,
        stds,
        y_label,
    }])
}

/// Panels (e.g. image, radar, GT, predictions) side by side — in two rows when more than
/// three would make the picture wider than 2400 px — each with its caption above it, and one
/// shared colour bar in metres (0..`max_m`, the [`colorize_depth`] map: near = red) at the
/// bottom. Panels of different sizes are centred in cells of the largest size. PNG bytes.
/// Captions, tick labels and the colour bar's metres in the embedded DejaVu Sans.
pub fn picture_row_png(
    panels: &[(&str, image::RgbImage)],
    max_m: f32,
) -> Result<Vec<u8>, VizError> {
    if panels.is_empty() {
        return Err(VizError::NoPanels);
    }
    let text = fonts_available();
    let g = PictureGrid::new(panels, text);
    let mut canvas = image::RgbImage::from_pixel(g.w, g.h, image::Rgb([255, 255, 255]));
    let origins = g.paste_panels(&mut canvas, panels);
    g.draw_colour_bar(&mut canvas, max_m);
    if text {
        canvas = g.draw_text(canvas, panels, &origins, max_m)?;
    }
    encode_rgb(&canvas)
}

/// Layout of a [`picture_row_png`] picture (pixels): cells of the largest panel size in
/// `rows` × `cols`, each with a caption strip above, then the colour bar and its ticks.
struct PictureGrid {
    /// Cell width and height.
    cw: u32,
    ch: u32,
    cols: u32,
    gap: u32,
    /// Caption strip above each cell.
    cap_h: u32,
    bar_h: u32,
    /// Picture size.
    w: u32,
    h: u32,
    /// Height of the panel grid (the colour bar starts there).
    grid_h: u32,
    /// Colour bar left edge and width.
    bx0: u32,
    bw: u32,
}

impl PictureGrid {
    fn new(panels: &[(&str, image::RgbImage)], text: bool) -> PictureGrid {
        let cw = panels
            .iter()
            .map(|(_, p)| p.width())
            .max()
            .unwrap_or(1)
            .max(1);
        let ch = panels
            .iter()
            .map(|(_, p)| p.height())
            .max()
            .unwrap_or(1)
            .max(1);
        let n = panels.len() as u32;
        let rows = if n > 3 && n * cw > 2400 { 2 } else { 1 };
        let cols = n.div_ceil(rows);
        let (gap, cap_h) = (8u32, if text { 26u32 } else { 4 });
        let bar_h = 18u32;
        let tick_h = if text { 40u32 } else { 8 };
        let w = cols * cw + (cols + 1) * gap;
        let grid_h = rows * (cap_h + ch) + (rows + 1) * gap;
        let h = grid_h + bar_h + tick_h + gap;
        let (bx0, bw) = (gap + cw / 8, (w - 2 * gap - cw / 4).max(2));
        PictureGrid {
            cw,
            ch,
            cols,
            gap,
            cap_h,
            bar_h,
            w,
            h,
            grid_h,
            bx0,
            bw,
        }
    }

    /// Paste each panel centred in its cell; the top-left corners of the cells (captions).
    fn paste_panels(
        &self,
        canvas: &mut image::RgbImage,
        panels: &[(&str, image::RgbImage)],
    ) -> Vec<(u32, u32)> {
        let (cw, ch, gap, cap_h) = (self.cw, self.ch, self.gap, self.cap_h);
        let mut origins = vec![];
        for (i, (_, p)) in panels.iter().enumerate() {
            let (r, c) = (i as u32 / self.cols, i as u32 % self.cols);
            let x = gap + c * (cw + gap) + (cw - p.width()) / 2;
            let y = gap + r * (cap_h + ch + gap) + cap_h + (ch - p.height()) / 2;
            image::imageops::replace(canvas, p, x as i64, y as i64);
            origins.push((gap + c * (cw + gap), gap + r * (cap_h + ch + gap)));
        }
        origins
    }

    /// Colour bar: the colorize_depth map itself, sampled at pixel centres.
    fn draw_colour_bar(&self, canvas: &mut image::RgbImage, max_m: f32) {
        let (bx0, bw, by0) = (self.bx0, self.bw, self.grid_h);
        let ramp: Vec<f32> = (0..bw)
            .map(|x| (x as f32 + 0.5) / bw as f32 * max_m)
            .collect();
        let bar = colorize_depth(&ramp, bw, 1, max_m);
        for y in 0..self.bar_h {
            for x in 0..bw {
                canvas.put_pixel(bx0 + x, by0 + y, *bar.get_pixel(x, 0));
            }
        }
    }

    /// The captions at the cell `origins`, the colour bar's 5 ticks with their labels (metres)
    /// and its "depth (m)" title, drawn on `canvas`.
    fn draw_text(
        &self,
        canvas: image::RgbImage,
        panels: &[(&str, image::RgbImage)],
        origins: &[(u32, u32)],
        max_m: f32,
    ) -> Result<image::RgbImage, VizError> {
        let (w, h) = (self.w, self.h);
        let (bx0, bw, by0, bar_h) = (self.bx0, self.bw, self.grid_h, self.bar_h);
        let mut buf = canvas.into_raw();
        {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            let cap_style = ("sans-serif", 20).into_font().color(&BLACK);
            for ((name, _), (x, y)) in panels.iter().zip(origins) {
                root.draw(&Text::new(
                    name.to_string(),
                    (*x as i32 + 2, *y as i32 + 3),
                    cap_style.clone(),
                ))
                .map_err(plot_err)?;
            }
            let tick_style = ("sans-serif", 15).into_font().color(&BLACK);
            let ticks = 4;
            for t in 0..=ticks {
                let f = t as f32 / ticks as f32;
                let x = bx0 as i32 + (f * (bw - 1) as f32) as i32;
                let y = (by0 + bar_h) as i32;
                root.draw(&PathElement::new(vec![(x, y), (x, y + 5)], BLACK))
                    .map_err(plot_err)?;
                let label = format!("{:.0}", f * max_m);
                root.draw(&Text::new(label, (x - 6, y + 7), tick_style.clone()))
                    .map_err(plot_err)?;
            }
            root.draw(&Text::new(
                "depth (m)".to_string(),
                ((bx0 + bw / 2) as i32 - 30, (by0 + bar_h) as i32 + 22),
                tick_style,
            ))
            .map_err(plot_err)?;
            root.present().map_err(plot_err)?;
        }
        image::RgbImage::from_raw(w, h, buf).ok_or_else(|| VizError::BufferSize("picture"))
    }
}

/// One panel of [`line_charts_png`]: named series of (x, y) points, one colour each.
pub struct LinePanel<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub series: &'a [(&'a str, Vec<(f64, f64)>)],
    /// Per series (same order), per point: the half-height of a vertical error bar in the
    /// series' colour (NaN: none). Empty: no error bars.
    pub error_bars: &'a [Vec<f64>],
    /// The x values are log10 of the quantity: ticks are labelled with 10^x.
    pub log10_x: bool,
}

/// The (x, y − e, y + e) error bars of series `i` of a panel (finite ones only).
fn error_bars(p: &LinePanel<'_>, i: usize) -> Vec<(f64, f64, f64)> {
    let (Some((_, pts)), Some(errs)) = (p.series.get(i), p.error_bars.get(i)) else {
        return vec![];
    };
    pts.iter()
        .zip(errs)
        .filter(|((x, y), e)| x.is_finite() && y.is_finite() && e.is_finite())
        .map(|(&(x, y), &e)| (x, y - e.abs(), y + e.abs()))
        .collect()
}

/// A tick label of a log10 axis: 10^x to 2 significant digits (2.0 → "100", 2.2 → "160").
fn log10_tick(x: &f64) -> String {
    let v = 10f64.powf(*x);
    let k = v.log10().floor() as i32;
    let unit = 10f64.powi(k - 1);
    let r = (v / unit).round() * unit;
    if k >= 1 {
        format!("{r:.0}")
    } else {
        format!("{r:.prec$}", prec = (1 - k) as usize)
    }
}

/// Axis ranges of a line panel: the finite points' extent (0..1 each when none, at least
/// 1e-6 wide, error bars included), y padded by 8 %, x by 3 % when there are error bars.
fn line_ranges(p: &LinePanel<'_>) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let pts = p.series.iter().flat_map(|(_, s)| s.iter().copied());
    let bars = (0..p.series.len())
        .flat_map(|i| error_bars(p, i))
        .flat_map(|(x, lo, hi)| [(x, lo), (x, hi)]);
    let finite: Vec<(f64, f64)> = pts
        .chain(bars)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    let lo_hi = |f: fn(&(f64, f64)) -> f64| {
        finite
            .iter()
            .map(f)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            })
    };
    let (mut x0, mut x1) = lo_hi(|p| p.0);
    let (mut y0, mut y1) = lo_hi(|p| p.1);
    if !x0.is_finite() {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    x1 = x1.max(x0 + 1e-6);
    y1 = y1.max(y0 + 1e-6);
    let pad = (y1 - y0) * 0.08;
    // Error bars at the first and last x stay inside the plot.
    let x_pad = if p.error_bars.is_empty() {
        0.0
    } else {
        (x1 - x0) * 0.03
    };
    ((x0 - x_pad)..(x1 + x_pad), (y0 - pad)..(y1 + pad))
}

fn line_panel(area: &Area<'_>, p: &LinePanel<'_>, text: bool) -> Result<(), VizError> {
    let (xs, ys) = line_ranges(p);
    let mut chart = chart_builder(area, p.title, text, 14, (36, 56))
        .build_cartesian_2d(xs, ys)
        .map_err(plot_err)?;
    let mut mesh = chart.configure_mesh();
    if text {
        mesh.x_desc(p.x_label).y_desc(p.y_label);
        if p.log10_x {
            mesh.x_label_formatter(&log10_tick);
        }
    } else {
        mesh.x_labels(0).y_labels(0);
    }
    mesh.draw().map_err(plot_err)?;
    let cap = (chart.x_range().end - chart.x_range().start) * 0.008;
    for (i, (name, s)) in p.series.iter().enumerate() {
        let data: Vec<(f64, f64)> = s.iter().filter(|(_, y)| y.is_finite()).copied().collect();
        draw_line(&mut chart, i, name, data, text, true)?;
        let c = COLOURS[i % COLOURS.len()];
        for (x, lo, hi) in error_bars(p, i) {
            let segments = [
                vec![(x, lo), (x, hi)],
                vec![(x - cap, lo), (x + cap, lo)],
                vec![(x - cap, hi), (x + cap, hi)],
            ];
            for seg in segments {
                chart
                    .draw_series(std::iter::once(PathElement::new(seg, c.stroke_width(2))))
                    .map_err(plot_err)?;
            }
        }
    }
    if text {
        draw_legend(&mut chart, Some(SeriesLabelPosition::UpperLeft))?;
    }
    Ok(())
}

/// Line charts side by side (one per panel, 520 px wide each), PNG bytes.
pub fn line_charts_png(panels: &[LinePanel<'_>]) -> Result<Vec<u8>, VizError> {
    panels_png(panels, 520, line_panel)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_are_typed_with_the_same_messages() {
        let e = picture_row_png(&[], 80.0).unwrap_err();
        assert!(matches!(e, VizError::NoPanels));
        assert_eq!(e.to_string(), "picture row: no panels");
        assert_eq!(
            VizError::BufferSize("plot").to_string(),
            "plot buffer has the wrong size"
        );
    }

    #[test]
    fn the_embedded_font_draws_text() {
        assert!(
            fonts_available(),
            "the embedded DejaVu Sans did not register"
        );
        // A white panel under a caption: the caption band above the panel holds dark glyph
        // pixels (the colour bar is at the bottom).
        let panel = image::RgbImage::from_pixel(200, 100, image::Rgb([255, 255, 255]));
        let png = picture_row_png(&[("WWWW", panel)], 80.0).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let band = img.height() / 5;
        let dark = img
            .enumerate_pixels()
            .filter(|(_, y, p)| *y < band && p.0.iter().all(|&c| c < 100))
            .count();
        assert!(dark > 20, "no caption drawn ({dark} dark pixels)");
    }

    #[test]
    fn iteration_ticks_are_whole_iterations() {
        assert_eq!(iteration_ticks(&(0.0..6.0)), 7);
        assert_eq!(iteration_ticks(&(0.0..1.0)), 2);
        assert_eq!(iteration_ticks(&(0.0..350.0)), 10);
        assert_eq!(iteration_tick(&3.0), "3");
        assert_eq!(iteration_tick(&2.5), "");
        assert_eq!(iteration_tick(&350.0000001), "350");
    }

    #[test]
    fn log10_ticks_and_error_bars() {
        assert_eq!(log10_tick(&2.0), "100");
        assert_eq!(log10_tick(&2.2), "160");
        assert_eq!(log10_tick(&3.4771212547), "3000");
        assert_eq!(log10_tick(&1.3), "20");
        assert_eq!(log10_tick(&0.0), "1.0");
        assert_eq!(log10_tick(&-1.0), "0.10");
        let series = [("a", vec![(2.0, 1.0), (3.0, 2.0)])];
        let errs = [vec![0.5, f64::NAN]];
        let p = LinePanel {
            title: "t",
            x_label: "x",
            y_label: "y",
            series: &series,
            error_bars: &errs,
            log10_x: true,
        };
        assert_eq!(error_bars(&p, 0), vec![(2.0, 0.5, 1.5)]);
        // the y range holds the bars: 0.5 .. 2.0, padded 8 %
        let (_, ys) = line_ranges(&p);
        assert!((ys.start - (0.5 - 0.12)).abs() < 1e-9 && (ys.end - 2.12).abs() < 1e-9);
        let png = line_charts_png(&[p]).unwrap();
        assert_eq!(image::load_from_memory(&png).unwrap().width(), 520);
    }

    #[test]
    fn curves_of_a_short_run_draw() {
        let loss = [(1u64, 3.0), (2, 2.0), (3, 1.5)];
        let val = [(0u64, 9.0), (3, 7.5)];
        let png = curves_png(&[("train loss", &loss)], &[("val RMSE (m)", &val)]).unwrap();
        let img = image::load_from_memory(&png).unwrap();
        assert_eq!((img.width(), img.height()), (1200, 450));
    }
}
