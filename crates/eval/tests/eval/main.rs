//! The eval crate's one integration-test binary (each test binary links libtorch, and linking
//! dominates the test build; issue 35):
//! - `eval_known_answers`: `eval` and `eval --predictions` on hand-computed answers;
//! - `predict_raw`: `predict` from raw nuScenes files;
//! - `released_real_keyframe`: the authors' checkpoint layout on the real keyframe (the
//!   reference network of the model crate's tests, `reference`).

mod eval_known_answers;
mod predict_raw;
#[path = "../../../checkpoint/tests/model/support/reference.rs"]
mod reference;
mod released_real_keyframe;
