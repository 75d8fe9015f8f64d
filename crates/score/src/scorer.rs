//! The one scorer (SPEC §9): every depth map depthsense scores — a network's in training,
//! `eval --checkpoint`, every experiment, another method's files in `eval --predictions` —
//! enters the metrics through [`score_image`].

use depthsense_dataset::DataError;
use depthsense_metrics::{EvalImage, Evaluator};
use depthsense_prep::layout::Condition;

/// Names of conditions as the metrics rows use them.
pub fn condition_names(c: &[Condition]) -> Vec<&'static str> {
    c.iter()
        .map(|c| match c {
            Condition::Day => "day",
            Condition::Night => "night",
            Condition::Rain => "rain",
        })
        .collect()
}

/// The one scorer (SPEC §9): one image's prediction (metres, row-major, training frame)
/// against its sparse GT, low-height mask (empty = absent) and scene conditions.
pub fn score_image(
    ev: &mut Evaluator,
    sparse_m: &[f32],
    lowheight: &[bool],
    conditions: &[Condition],
    pred_m: &[f32],
) -> Result<(), DataError> {
    let conds = condition_names(conditions);
    ev.add(&EvalImage {
        pred_m,
        gt_m: sparse_m,
        lowheight: (!lowheight.is_empty()).then_some(lowheight),
        conditions: &conds,
    })?;
    Ok(())
}
