//! The Python module `depthsense` (PyO3; `make python` builds the wheel with maturin into
//! `.venv`). No libtorch: a deployment feeds an exported graph (onnxruntime, TensorRT) with
//! what this module computes.
//!
//! - [`inputs_from_raw`] / [`inputs_from_sample`]: the exported graph's inputs (`image`,
//!   `radar`) from raw files (a CAM_FRONT JPEG as a path or bytes, radar `.pcd` files, the
//!   calibration JSON) or a prepared sample — the arrays `depthsense predict` feeds its network,
//!   bit for bit, because both are built by `depthsense_data::net_input`;
//! - [`read_sample`] / [`read_radar_points`] / [`read_depth`]: a prepared sample's files as
//!   numpy (every map in metres, the low-height mask as booleans, `meta.json` as a dict,
//!   `radar_points.bin` as structured arrays), a 16-bit depth PNG (`predict`'s depth.png);
//! - [`score`] / [`score_sample`]: depth maps scored with the evaluation protocol
//!   (`depthsense_score::score_image`, the one scorer of `eval`), its report as a dict.
//!
//! docs/guide/deploy.md, "From Python", has the recipe and the prepared sample's formats.

use std::ffi::CString;
use std::path::{Path, PathBuf};

use depthsense_base::words::Words;
use depthsense_config::RadarInput;
use depthsense_data::net_input::{self, NetInputs, PredictInput};
use depthsense_dataset::DataError;
use depthsense_metrics::{Aggregate, EvalConfig, Evaluator, Protocol, Report};
use depthsense_nuscenes::depth_png::DepthMap;
use depthsense_prep::calibration::RadarSettings;
use depthsense_prep::layout::{self, Condition};
use depthsense_prep::radar_points::{RadarPoints, RADAR_POINTS_FILE};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};

/// A data-layer error as a Python exception: files that cannot be read are `OSError`, the rest
/// `ValueError`; the message is the one `depthsense` prints.
fn py_err(e: DataError) -> PyErr {
    match e {
        DataError::Io { .. } => PyOSError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    }
}

fn value_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The radar input a model takes and the radar it was trained on, from `radar_input` (a word:
/// height, raw, raw-height, mer, or none for an RGB-only model) or an export sidecar
/// (`FILE.json` of `depthsense export`: its `radar_input` and `trained_radar`).
fn model_radar(
    radar_input: Option<&str>,
    sidecar: Option<PathBuf>,
) -> PyResult<(Option<RadarInput>, Option<RadarSettings>)> {
    match (radar_input, sidecar) {
        (Some(_), Some(_)) => Err(PyValueError::new_err(
            "give radar_input or sidecar, not both: the sidecar records the model's radar input",
        )),
        (None, None) => Err(PyValueError::new_err(
            "give the model's radar input: sidecar=\"model.onnx.json\" (written by `depthsense \
             export` beside the model) or radar_input=\"height\" | \"raw\" | \"raw-height\" | \
             \"mer\" | \"none\" (RGB-only)",
        )),
        (Some("none"), None) => Ok((None, None)),
        (Some(word), None) => {
            let r = <RadarInput as Words>::parse_word(word).map_err(value_err)?;
            Ok((Some(r), None))
        }
        (None, Some(path)) => {
            let bytes = std::fs::read(&path)
                .map_err(|e| PyOSError::new_err(format!("{}: {e}", path.display())))?;
            let json: serde_json::Value = serde_json::from_slice(&bytes)
                .map_err(|e| value_err(format!("{}: cannot parse: {e}", path.display())))?;
            let Some(kind) = json.get("radar_input") else {
                return Err(value_err(format!(
                    "{}: no \"radar_input\": not an export sidecar (FILE.json beside a model \
                     `depthsense export` wrote)",
                    path.display()
                )));
            };
            let radar: Option<RadarInput> = serde_json::from_value(kind.clone())
                .map_err(|e| value_err(format!("{}: radar_input: {e}", path.display())))?;
            let trained = json
                .get("trained_radar")
                .and_then(|t| serde_json::from_value(t.clone()).ok());
            Ok((radar, trained))
        }
    }
}

/// `[C, H, W]` values as a float32 array of shape `[1, C, H, W]`.
fn batch_of_one<'py>(
    py: Python<'py>,
    values: Vec<f32>,
    c: usize,
    h: usize,
    w: usize,
) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, values)
        .reshape([1, c, h, w])?
        .into_any())
}

/// The graph's inputs as a dict {"image", "radar"} (no "radar" for an RGB-only model), each
/// float32 [1, C, H, W]; one warning per way the input's radar differs from training's.
fn inputs_dict<'py>(
    py: Python<'py>,
    input: &PredictInput,
    radar: Option<RadarInput>,
    trained: Option<&RadarSettings>,
) -> PyResult<Bound<'py, PyDict>> {
    for w in net_input::radar_warnings(trained, input) {
        let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
        let msg = CString::new(w).unwrap_or_default();
        PyErr::warn(py, category.as_any(), &msg, 2)?;
    }
    let NetInputs {
        width,
        height,
        image,
        radar: planes,
        radar_channels,
    } = net_input::net_inputs(input, radar).map_err(py_err)?;
    let d = PyDict::new(py);
    d.set_item("image", batch_of_one(py, image, 3, height, width)?)?;
    if radar.is_some() {
        d.set_item(
            "radar",
            batch_of_one(py, planes, radar_channels, height, width)?,
        )?;
    }
    Ok(d)
}

/// The exported graph's inputs for raw files, exactly what `depthsense predict --image IMAGE
/// --calibration CALIBRATION [--radar ...]` feeds its network:
///
/// - image: the 1600x900 CAM_FRONT JPEG, as a path or its bytes;
/// - calibration: the calibration JSON (`depthsense calibration` writes one);
/// - radar: the radar .pcd paths to use (each listed in the calibration, matched by file name);
///   None: every file the calibration lists;
/// - radar_input ("height", "raw", "raw-height", "mer", "none") or sidecar (the export's
///   FILE.json): which radar maps the model takes; with a sidecar, a radar gathered otherwise
///   than in training gives a UserWarning, as `predict` warns;
/// - radar_filters=False: keep every radar point (`predict --no-radar-filters`).
///
/// Returns {"image": float32 [1, 3, 350, 800] RGB in [0, 1], "radar": float32 [1, C, 350, 800]
/// metres, 0 = no return} ("radar" absent for an RGB-only model): `session.run(None, inputs)`.
/// A MER model's radar needs the PDA network (`predict --mer-checkpoint`): ValueError here.
#[pyfunction]
#[pyo3(signature = (image, calibration, radar=None, *, radar_input=None, sidecar=None, radar_filters=true))]
fn inputs_from_raw<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    calibration: PathBuf,
    radar: Option<Vec<PathBuf>>,
    radar_input: Option<&str>,
    sidecar: Option<PathBuf>,
    radar_filters: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let (kind, trained) = model_radar(radar_input, sidecar)?;
    let files = radar.unwrap_or_default();
    let input = if let Ok(bytes) = image.cast::<PyBytes>() {
        net_input::input_from_raw_bytes(
            bytes.as_bytes(),
            "image",
            &files,
            &calibration,
            radar_filters,
        )
    } else {
        let path: PathBuf = image.extract().map_err(|_| {
            PyValueError::new_err("image: a path (str or os.PathLike) or the file's bytes")
        })?;
        net_input::input_from_raw(&path, &files, &calibration, radar_filters)
    }
    .map_err(py_err)?;
    inputs_dict(py, &input, kind, trained.as_ref())
}

/// The exported graph's inputs for a prepared sample folder (PREPARED/<sample token>), exactly
/// what `depthsense predict --sample SAMPLE` feeds its network; arguments and result as
/// `inputs_from_raw` (a MER model reads the maps `depthsense mer apply` wrote).
#[pyfunction]
#[pyo3(signature = (sample, *, radar_input=None, sidecar=None))]
fn inputs_from_sample<'py>(
    py: Python<'py>,
    sample: PathBuf,
    radar_input: Option<&str>,
    sidecar: Option<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let (kind, trained) = model_radar(radar_input, sidecar)?;
    let input = net_input::input_from_prepared(&sample).map_err(py_err)?;
    inputs_dict(py, &input, kind, trained.as_ref())
}

/// A depth map as float32 [H, W] metres.
fn depth_array<'py>(py: Python<'py>, m: DepthMap) -> PyResult<Bound<'py, PyAny>> {
    let (h, w) = (m.height as usize, m.width as usize);
    Ok(PyArray1::from_vec(py, m.depth_m)
        .reshape([h, w])?
        .into_any())
}

/// JSON text as Python objects (the `json` module's own parse).
fn json_loads<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}

/// radar_points.bin as a dict (see `read_radar_points`).
fn radar_points_dict<'py>(py: Python<'py>, p: &RadarPoints) -> PyResult<Bound<'py, PyDict>> {
    let np = py.import("numpy")?;
    let d = PyDict::new(py);
    let cam = PyDict::new(py);
    let c = &p.camera;
    cam.set_item("fx", c.fx)?;
    cam.set_item("fy", c.fy)?;
    cam.set_item("cx", c.cx)?;
    cam.set_item("cy", c.cy)?;
    cam.set_item("width", c.width)?;
    cam.set_item("height", c.height)?;
    d.set_item("camera", cam)?;
    d.set_item("channels", PyList::new(py, &p.channels)?)?;
    // Groups: one record per (channel, sweep).
    let group_dtype = json_loads(
        py,
        r#"[["channel", "<u2"], ["sweep", "<u2"], ["origin", "<f4", [3]], ["n_points", "<u4"]]"#,
    )?;
    let groups = np.call_method1("zeros", (p.groups.len(), to_dtype(&np, &group_dtype)?))?;
    let col = |name: &str, v: Bound<'py, PyAny>| groups.set_item(name, v);
    col(
        "channel",
        PyArray1::from_vec(py, p.groups.iter().map(|g| g.channel).collect()).into_any(),
    )?;
    col(
        "sweep",
        PyArray1::from_vec(py, p.groups.iter().map(|g| g.sweep).collect()).into_any(),
    )?;
    col(
        "origin",
        PyArray1::from_vec(py, p.groups.iter().flat_map(|g| g.origin_cam).collect())
            .reshape([p.groups.len(), 3])?
            .into_any(),
    )?;
    col(
        "n_points",
        PyArray1::from_vec(py, p.groups.iter().map(|g| g.n_points).collect()).into_any(),
    )?;
    d.set_item("groups", &groups)?;
    // Points: one record per return, with its group's channel and sweep.
    let point_dtype = json_loads(
        py,
        r#"[["channel", "<u2"], ["sweep", "<u2"], ["x", "<f4"], ["y", "<f4"], ["z", "<f4"]]"#,
    )?;
    let n = p.points_cam.len();
    let points = np.call_method1("zeros", (n, to_dtype(&np, &point_dtype)?))?;
    let (mut ch, mut sw) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for (g, r) in p.group_ranges() {
        ch.extend(std::iter::repeat_n(g.channel, r.len()));
        sw.extend(std::iter::repeat_n(g.sweep, r.len()));
    }
    points.set_item("channel", PyArray1::from_vec(py, ch))?;
    points.set_item("sweep", PyArray1::from_vec(py, sw))?;
    for (i, axis) in ["x", "y", "z"].iter().enumerate() {
        let v: Vec<f32> = p.points_cam.iter().map(|q| q[i]).collect();
        points.set_item(*axis, PyArray1::from_vec(py, v))?;
    }
    d.set_item("points", points)?;
    Ok(d)
}

/// A numpy dtype from its JSON description (lists → tuples).
fn to_dtype<'py>(
    np: &Bound<'py, PyModule>,
    fields: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let py = np.py();
    let tuples = PyList::empty(py);
    for f in fields.try_iter()? {
        let f = f?;
        let items: Vec<Bound<'py, PyAny>> = f.extract()?;
        let mut parts: Vec<Bound<'py, PyAny>> = vec![];
        for (i, it) in items.into_iter().enumerate() {
            if i == 2 {
                let shape: Vec<usize> = it.extract()?;
                parts.push(pyo3::types::PyTuple::new(py, shape)?.into_any());
            } else {
                parts.push(it);
            }
        }
        tuples.append(pyo3::types::PyTuple::new(py, parts)?)?;
    }
    np.call_method1("dtype", (tuples,))
}

/// A 16-bit depth PNG (value = depth × 256, 0 = no data: `predict`'s depth.png, a prepared
/// sample's lidar and radar maps) as float32 [H, W] metres, read as depthsense reads it.
#[pyfunction]
fn read_depth<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyAny>> {
    depth_array(py, depthsense_dataset::read_depth(&path).map_err(py_err)?)
}

fn read_points(path: &Path) -> PyResult<RadarPoints> {
    let bytes =
        std::fs::read(path).map_err(|e| PyOSError::new_err(format!("{}: {e}", path.display())))?;
    RadarPoints::decode(&bytes, path).map_err(value_err)
}

/// A `radar_points.bin` (the radar returns behind a prepared sample's radar maps) as a dict:
/// "camera" {fx, fy, cx, cy, width, height} (full resolution), "channels" (names), "groups"
/// (structured array: channel u2 (index into channels), sweep u2 (0 = keyframe), origin f4[3]
/// (the radar in the camera frame, m), n_points u4) and "points" (structured array, one record
/// per return: channel u2, sweep u2, x, y, z f4 — camera frame, metres, x right, y down,
/// z forward). docs/guide/deploy.md has the byte layout.
#[pyfunction]
fn read_radar_points<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    radar_points_dict(py, &read_points(&path)?)
}

/// Every file of a prepared sample folder (PREPARED/<sample token>) as numpy, decoded as
/// depthsense reads it: "image" uint8 [350, 800, 3] RGB; "lidar_sparse", "lidar_dense",
/// "radar_raw", "radar_height" (and "radar_mer_depth" where `mer apply` wrote it) float32
/// [350, 800] metres, 0 = no data; "radar_mer_conf" float32 [350, 800] in [0, 1];
/// "lowheight_mask" bool [350, 800] (True where the file holds 255); "meta" (meta.json as a
/// dict); "radar_points" (radar_points.bin, as `read_radar_points`). A file the folder does
/// not hold is absent from the dict; without meta.json it is not a sample: ValueError.
#[pyfunction]
fn read_sample<'py>(py: Python<'py>, sample: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let dir = sample.as_path();
    // The same advice as `predict --sample`.
    depthsense_dataset::check_sample_dir(dir).map_err(py_err)?;
    let meta_path = dir.join(layout::META_FILE);
    let d = PyDict::new(py);
    let rgb = depthsense_dataset::decode_rgb(&dir.join(layout::IMAGE_FILE)).map_err(py_err)?;
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    d.set_item(
        "image",
        PyArray1::from_vec(py, rgb.into_raw()).reshape([h, w, 3])?,
    )?;
    for (key, file) in [
        ("lidar_sparse", layout::LIDAR_SPARSE_FILE),
        ("lidar_dense", layout::LIDAR_DENSE_FILE),
        ("radar_raw", layout::RADAR_RAW_FILE),
        ("radar_height", layout::RADAR_HEIGHT_FILE),
    ] {
        let p = dir.join(file);
        if p.exists() {
            let m = depthsense_dataset::read_depth(&p).map_err(py_err)?;
            d.set_item(key, depth_array(py, m)?)?;
        }
    }
    if dir.join(layout::MER_DEPTH_FILE).exists() {
        let (depth, conf) = depthsense_dataset::mer_maps::read_mer_maps(dir).map_err(py_err)?;
        d.set_item("radar_mer_depth", depth_array(py, depth)?)?;
        d.set_item("radar_mer_conf", depth_array(py, conf)?)?;
    }
    let mask = depthsense_dataset::read_lowheight_mask(dir, w, h).map_err(py_err)?;
    if !mask.is_empty() {
        d.set_item(
            "lowheight_mask",
            PyArray1::from_vec(py, mask).reshape([h, w])?,
        )?;
    }
    let meta = std::fs::read_to_string(&meta_path)
        .map_err(|e| PyOSError::new_err(format!("{}: {e}", meta_path.display())))?;
    d.set_item("meta", json_loads(py, &meta)?)?;
    let points = dir.join(RADAR_POINTS_FILE);
    if points.exists() {
        d.set_item(
            "radar_points",
            radar_points_dict(py, &read_points(&points)?)?,
        )?;
    }
    Ok(d)
}

/// One image or a list of them as float32 [H, W] maps (any real dtype, any 2-D shape).
fn maps_arg<'py>(obj: &Bound<'py, PyAny>, what: &str) -> PyResult<Vec<(Vec<f32>, usize, usize)>> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let items: Vec<Bound<'py, PyAny>> = if obj.is_instance_of::<PyList>() {
        obj.extract()?
    } else {
        vec![obj.clone()]
    };
    items
        .iter()
        .map(|it| {
            let a = np.call_method1("ascontiguousarray", (it, "float32"))?;
            let a: PyReadonlyArrayDyn<'py, f32> = a
                .extract()
                .map_err(|_| PyValueError::new_err(format!("{what}: not an array of numbers")))?;
            if a.ndim() != 2 {
                let shape = a.shape().to_vec();
                return Err(PyValueError::new_err(format!(
                    "{what}: a [H, W] depth map (or a list of them), got shape {shape:?}"
                )));
            }
            let (h, w) = (a.shape()[0], a.shape()[1]);
            Ok((a.as_slice()?.to_vec(), h, w))
        })
        .collect()
}

/// The evaluation's settings from the keyword arguments.
fn eval_config(
    protocol: &str,
    aggregate: &str,
    caps: Vec<f64>,
    clip: (f64, f64),
) -> PyResult<EvalConfig> {
    Ok(EvalConfig {
        caps_m: caps,
        protocol: protocol.parse::<Protocol>().map_err(value_err)?,
        aggregate: aggregate.parse::<Aggregate>().map_err(value_err)?,
        clip_min_m: clip.0,
        clip_max_m: clip.1,
    })
}

fn parse_conditions(words: &[String]) -> PyResult<Vec<Condition>> {
    words
        .iter()
        .map(|w| {
            serde_json::from_value(serde_json::Value::String(w.clone())).map_err(|_| {
                PyValueError::new_err(format!("condition {w:?}: one of day, night, rain"))
            })
        })
        .collect()
}

/// The report as a dict: the JSON `eval` writes in tables.json ("report" of each model).
fn report_dict<'py>(py: Python<'py>, r: &Report) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(r).map_err(value_err)?;
    let d = json_loads(py, &text)?;
    if let Some(h) = r.headline() {
        let t = serde_json::to_string(h).map_err(value_err)?;
        d.set_item("headline", json_loads(py, &t)?)?;
    }
    Ok(d)
}

/// Scores depth maps with the evaluation protocol (SPEC §9), through the scorer of `depthsense
/// eval` (`score_image`): pred and gt are one [H, W] map in metres (gt 0 = no data) or lists of
/// them (one evaluation over every image); lowheight: the low-height masks (bool, or the file's
/// 0/255), one per image, or None; conditions: each image's scene conditions (a list of
/// "day" / "night" / "rain"; one list for a single image), default day.
///
/// Returns the report as `eval` writes it in tables.json: {"config", "images_seen", "rows":
/// [{condition, region, cap_m, n_images, n_pixels, metrics: {delta1, delta2, delta3, abs_rel,
/// sq_rel, rmse, rmse_log, mae}}], "headline": the combined / full / largest-cap row}.
#[pyfunction]
#[pyo3(signature = (pred, gt, lowheight=None, conditions=None, *, protocol="mask", aggregate="image", caps=vec![50.0, 70.0, 80.0], clip=(1.0, 80.0)))]
#[allow(clippy::too_many_arguments)]
fn score<'py>(
    py: Python<'py>,
    pred: &Bound<'py, PyAny>,
    gt: &Bound<'py, PyAny>,
    lowheight: Option<&Bound<'py, PyAny>>,
    conditions: Option<&Bound<'py, PyAny>>,
    protocol: &str,
    aggregate: &str,
    caps: Vec<f64>,
    clip: (f64, f64),
) -> PyResult<Bound<'py, PyAny>> {
    let preds = maps_arg(pred, "pred")?;
    let gts = maps_arg(gt, "gt")?;
    if preds.len() != gts.len() {
        return Err(PyValueError::new_err(format!(
            "{} predictions but {} ground truths",
            preds.len(),
            gts.len()
        )));
    }
    let masks = masks_arg(lowheight, preds.len())?;
    let conds = conditions_arg(conditions, preds.len())?;
    let mut ev =
        Evaluator::new(eval_config(protocol, aggregate, caps, clip)?).map_err(value_err)?;
    for (i, ((p, g), (m, c))) in preds
        .iter()
        .zip(&gts)
        .zip(masks.iter().zip(&conds))
        .enumerate()
    {
        if (p.1, p.2) != (g.1, g.2) {
            return Err(PyValueError::new_err(format!(
                "image {i}: prediction is {}x{} but the ground truth {}x{}",
                p.2, p.1, g.2, g.1
            )));
        }
        depthsense_score::score_image(&mut ev, &g.0, m, c, &p.0).map_err(py_err)?;
    }
    report_dict(py, &ev.finish())
}

/// `score`'s low-height masks: one per image of the `n` (a value > 0.5 is low height), or
/// empty masks when none are given.
fn masks_arg(lowheight: Option<&Bound<'_, PyAny>>, n: usize) -> PyResult<Vec<Vec<bool>>> {
    let masks: Vec<Vec<bool>> = match lowheight {
        None => vec![vec![]; n],
        Some(m) => maps_arg(m, "lowheight")?
            .into_iter()
            .map(|(v, _, _)| v.into_iter().map(|x| x > 0.5).collect())
            .collect(),
    };
    if masks.len() != n {
        return Err(PyValueError::new_err(format!(
            "{} low-height masks for {} images",
            masks.len(),
            n
        )));
    }
    Ok(masks)
}

/// `score`'s scene conditions: one list per image of the `n` (one list alone for a single
/// image), day when none are given.
fn conditions_arg(
    conditions: Option<&Bound<'_, PyAny>>,
    n: usize,
) -> PyResult<Vec<Vec<Condition>>> {
    let conds: Vec<Vec<Condition>> = match conditions {
        None => vec![vec![Condition::Day]; n],
        Some(c) => {
            let lists: Vec<Vec<String>> = match c.extract::<Vec<String>>() {
                Ok(one) if n == 1 => vec![one],
                _ => c.extract().map_err(|_| {
                    PyValueError::new_err(
                        "conditions: a list of \"day\" / \"night\" / \"rain\" per image",
                    )
                })?,
            };
            lists
                .iter()
                .map(|l| parse_conditions(l))
                .collect::<PyResult<_>>()?
        }
    };
    if conds.len() != n {
        return Err(PyValueError::new_err(format!(
            "{} condition lists for {} images",
            conds.len(),
            n
        )));
    }
    Ok(conds)
}

/// Scores one prediction ([350, 800] metres) against a prepared sample exactly as `depthsense
/// eval --predictions` scores it: its lidar_sparse.png, lowheight_mask.png and the scene
/// conditions of its meta.json. Returns the report as `score`.
#[pyfunction]
#[pyo3(signature = (pred, sample, *, protocol="mask", aggregate="image", caps=vec![50.0, 70.0, 80.0], clip=(1.0, 80.0)))]
fn score_sample<'py>(
    py: Python<'py>,
    pred: &Bound<'py, PyAny>,
    sample: PathBuf,
    protocol: &str,
    aggregate: &str,
    caps: Vec<f64>,
    clip: (f64, f64),
) -> PyResult<Bound<'py, PyAny>> {
    let dir = sample.as_path();
    let meta = depthsense_dataset::read_meta(dir).map_err(py_err)?;
    let gt_path = dir.join(layout::LIDAR_SPARSE_FILE);
    let gt = depthsense_dataset::read_depth(&gt_path).map_err(py_err)?;
    let (w, h) = (gt.width as usize, gt.height as usize);
    let mask = depthsense_dataset::read_lowheight_mask(dir, w, h).map_err(py_err)?;
    let mut preds = maps_arg(pred, "pred")?;
    let Some((p, ph, pw)) = preds.pop().filter(|_| preds.is_empty()) else {
        return Err(PyValueError::new_err("pred: one [H, W] depth map"));
    };
    if (pw, ph) != (w, h) {
        return Err(PyValueError::new_err(format!(
            "pred is {pw}x{ph} but the ground truth of the training frame is {w}x{h}"
        )));
    }
    let mut ev =
        Evaluator::new(eval_config(protocol, aggregate, caps, clip)?).map_err(value_err)?;
    depthsense_score::score_image(&mut ev, &gt.depth_m, &mask, &meta.conditions, &p)
        .map_err(py_err)?;
    report_dict(py, &ev.finish())
}

/// depthsense from Python, without libtorch: a network's exact inputs from raw files or a
/// prepared sample (for an exported model in onnxruntime), a prepared sample's files as numpy,
/// and the evaluation protocol's scorer. docs/guide/deploy.md, "From Python".
#[pymodule]
fn depthsense(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("FRAME_WIDTH", layout::FRAME_W)?;
    m.add("FRAME_HEIGHT", layout::FRAME_H)?;
    m.add_function(wrap_pyfunction!(inputs_from_raw, m)?)?;
    m.add_function(wrap_pyfunction!(inputs_from_sample, m)?)?;
    m.add_function(wrap_pyfunction!(read_sample, m)?)?;
    m.add_function(wrap_pyfunction!(read_radar_points, m)?)?;
    m.add_function(wrap_pyfunction!(read_depth, m)?)?;
    m.add_function(wrap_pyfunction!(score, m)?)?;
    m.add_function(wrap_pyfunction!(score_sample, m)?)?;
    Ok(())
}
