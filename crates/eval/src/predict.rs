//! `depthsense predict`: depth for one input, from
//! - a prepared sample directory (`prepare` output),
//! - a sample token of a nuScenes-format dataroot (the `prepare` code runs for that sample,
//!   with the radar settings the checkpoint was trained on), or
//! - raw files: a 1600x900 CAM_FRONT JPEG, radar `.pcd` files and a calibration JSON
//!   ([`depthsense_prep::calibration`]: the camera intrinsics and, per radar file, its channel,
//!   sweep index, time and sweep-sensor → keyframe-camera transform; `depthsense calibration`
//!   writes one from a nuScenes sample). The radar goes through `prepare`'s own function for
//!   every sweep, so the three inputs of one keyframe give the same maps, bit for bit.
//!
//! Outputs: `depth.png` (16-bit, depth×256, SPEC §3), `depth_color.png` (turbo),
//! `radar_overlay.png` (radar points over the image), `image.png` (the 800x350 frame).

use std::path::{Path, PathBuf};

use depthsense_base::fsutil::write_atomic;
use depthsense_config::RadarInput;
use depthsense_data::net_input::net_inputs;
use depthsense_model::DepthNet;
use depthsense_nuscenes::depth_png::{encode_png, DepthMap};
use tch::{Device, Kind, Tensor};

use depthsense_infer::NetError;

// The inputs are built without libtorch (`depthsense_data::net_input`), where the Python module
// `depthsense` builds them too: one path from files to the network's arrays.
pub use depthsense_data::net_input::{
    as_stored, input_from_prepared, input_from_raw, input_from_raw_bytes, input_from_tables,
    input_from_token, radar_warnings, trained_radar_settings, NetInputs, PredictInput,
};

/// Predict a depth map (metres, the input's frame size).
pub fn predict(
    net: &DepthNet,
    input: &PredictInput,
    radar: Option<RadarInput>,
    device: Device,
) -> Result<DepthMap, NetError> {
    depthsense_model::device::autotune_fixed_size(device);
    let x = net_inputs(input, radar)?;
    let (w, h) = (x.width as u32, x.height as u32);
    let img = Tensor::from_slice(&x.normalised_image())
        .view([1, 3, h as i64, w as i64])
        .to_device(device);
    let radar_t = if x.radar_channels == 0 {
        Tensor::zeros([1, 1, h as i64, w as i64], (Kind::Float, device))
    } else {
        Tensor::from_slice(&x.radar)
            .view([1, x.radar_channels as i64, h as i64, w as i64])
            .to_device(device)
    };
    let pred = tch::no_grad(|| net.decode(&net.forward_t(&img, &radar_t, false)));
    let pred = pred
        .to_device(Device::Cpu)
        .to_kind(Kind::Float)
        .contiguous();
    if pred.numel() != (w * h) as usize {
        return Err(NetError::OutputShape {
            what: "prediction",
            got: pred.size(),
            want: vec![1, 1, h as i64, w as i64],
        });
    }
    Ok(DepthMap {
        width: w,
        height: h,
        depth_m: Vec::<f32>::try_from(pred.view([-1]))?,
    })
}

/// The files [`write_outputs`] writes.
pub const OUTPUT_FILES: [&str; 4] = [
    "depth.png",
    "depth_color.png",
    "radar_overlay.png",
    "image.png",
];

/// Write depth.png, depth_color.png, radar_overlay.png and image.png into `out`.
pub fn write_outputs(
    out: &Path,
    input: &PredictInput,
    depth: &DepthMap,
    max_m: f32,
) -> Result<Vec<PathBuf>, NetError> {
    std::fs::create_dir_all(out).map_err(|e| NetError::io(out, e))?;
    let mut written = vec![];
    let mut w = |name: &str, bytes: Vec<u8>| -> Result<(), NetError> {
        let p = out.join(name);
        write_atomic(&p, &bytes).map_err(|e| NetError::io(&p, e))?;
        written.push(p);
        Ok(())
    };
    w("depth.png", encode_png(depth)?)?;
    let color =
        depthsense_viz::plot::colorize_depth(&depth.depth_m, depth.width, depth.height, max_m);
    w("depth_color.png", depthsense_viz::plot::encode_rgb(&color)?)?;
    let overlay =
        depthsense_viz::plot::overlay_points(&input.image, &input.radar_raw.depth_m, max_m, 3);
    w(
        "radar_overlay.png",
        depthsense_viz::plot::encode_rgb(&overlay)?,
    )?;
    w("image.png", depthsense_viz::plot::encode_rgb(&input.image)?)?;
    Ok(written)
}

/// Computes the MER maps of a `predict` input with a PDA network (`predict --mer-checkpoint`:
/// sample tokens and raw files carry no MER maps of their own).
pub fn attach_mer(
    input: &mut PredictInput,
    net: &depthsense_model::pda::PdaNet,
    device: Device,
) -> Result<(), NetError> {
    input.mer = Some(depthsense_mer::apply::mer_maps_for_image(
        &input.image,
        &input.radar_raw,
        net,
        device,
    )?);
    Ok(())
}
