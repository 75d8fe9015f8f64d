//! Curves (plotters bitmap backend into a buffer, PNG-encoded with `image`) and depth pictures
//! (colorous turbo colour map, radar overlays, error maps).
//!
//! Text needs a TrueType font: plotters' `ab_glyph` backend has none built in, so one is
//! looked up among common system font files at run time. Without one the curves are drawn
//! without text (axes and lines only) rather than failing.

use std::sync::OnceLock;

use plotters::prelude::*;

use crate::error::TrainError;

const FONT_CANDIDATES: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation/LiberationSans-Regular.ttf",
    "/Library/Fonts/Arial.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
    "C:\\Windows\\Fonts\\arial.ttf",
];

/// Register a system font with plotters once; true when text can be drawn.
pub fn fonts_available() -> bool {
    static OK: OnceLock<bool> = OnceLock::new();
    *OK.get_or_init(|| {
        for p in FONT_CANDIDATES {
            if let Ok(bytes) = std::fs::read(p) {
                let leaked: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, leaked).is_ok() {
                    return true;
                }
            }
        }
        false
    })
}

type Series<'a> = (&'a str, &'a [(u64, f64)]);

const COLOURS: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
];

fn plot_err<E: std::fmt::Debug>(e: E) -> TrainError {
    TrainError::Other(format!("plotting failed: {e:?}"))
}

fn panel(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    title: &str,
    series: &[Series<'_>],
    text: bool,
) -> Result<(), TrainError> {
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
    let mut b = ChartBuilder::on(area);
    b.margin(12);
    if text {
        b.caption(title, ("sans-serif", 18))
            .x_label_area_size(30)
            .y_label_area_size(50);
    } else {
        b.x_label_area_size(4).y_label_area_size(4);
    }
    let mut chart = b
        .build_cartesian_2d(x0..x1.max(x0 + 1.0), (y0 - pad)..(y1 + pad))
        .map_err(plot_err)?;
    let mut mesh = chart.configure_mesh();
    if text {
        mesh.x_desc("iteration");
    } else {
        mesh.disable_x_mesh()
            .disable_y_mesh()
            .x_labels(0)
            .y_labels(0);
    }
    mesh.draw().map_err(plot_err)?;
    for (i, (name, s)) in series.iter().enumerate() {
        let c = COLOURS[i % COLOURS.len()];
        let data: Vec<(f64, f64)> = s
            .iter()
            .filter(|(_, y)| y.is_finite())
            .map(|&(x, y)| (x as f64, y))
            .collect();
        let line = chart
            .draw_series(LineSeries::new(data.clone(), c.stroke_width(2)))
            .map_err(plot_err)?;
        if text {
            line.label(*name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c));
        }
        if data.len() < 60 {
            chart
                .draw_series(data.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(plot_err)?;
        }
    }
    if text {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(plot_err)?;
    }
    Ok(())
}

/// Two panels side by side (left: e.g. training loss; right: e.g. validation RMSE), PNG bytes.
pub fn curves_png(left: &[Series<'_>], right: &[Series<'_>]) -> Result<Vec<u8>, TrainError> {
    let (w, h) = (1200u32, 450u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    let text = fonts_available();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let (a, b) = root.split_horizontally(w / 2);
        panel(&a, "training loss", left, text)?;
        panel(&b, "validation", right, text)?;
        root.present().map_err(plot_err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| TrainError::Other("plot buffer has the wrong size".into()))?;
    encode_rgb(&img)
}

/// PNG-encode an RGB image.
pub fn encode_rgb(img: &image::RgbImage) -> Result<Vec<u8>, TrainError> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| TrainError::Other(format!("PNG encoding failed: {e}")))?;
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

/// De-normalise an ImageNet-normalised [3,H,W] image back to RGB8 (SPEC §6).
pub fn denormalise(chw: &[f32], w: u32, h: u32) -> image::RgbImage {
    let plane = (w * h) as usize;
    let mut img = image::RgbImage::new(w, h);
    for (i, p) in img.pixels_mut().enumerate() {
        for c in 0..3 {
            let x =
                chw[c * plane + i] * crate::data::IMAGENET_STD[c] + crate::data::IMAGENET_MEAN[c];
            p.0[c] = (x.clamp(0.0, 1.0) * 255.0).round() as u8;
        }
    }
    img
}
