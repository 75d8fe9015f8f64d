//! `tables.md`, `tables.csv` and `tables.json`: what `eval` writes (SPEC §10 items 1–3);
//! tables.json is a `depthsense_records::tables::TablesRecord`.

use std::path::{Path, PathBuf};

use depthsense_base::fsutil::write_atomic;
use depthsense_dataset::DataError;
use depthsense_metrics::{tables, Report};
use depthsense_records::tables::TablesRecord;
use depthsense_records::to_json_pretty;

/// The files [`write_tables`] writes.
pub const TABLE_FILES: [&str; 3] = ["tables.md", "tables.csv", "tables.json"];

/// [`TABLE_FILES`] in `dir`.
pub fn table_paths(dir: &Path) -> Vec<PathBuf> {
    TABLE_FILES.iter().map(|f| dir.join(f)).collect()
}

/// Write `tables.md`, `tables.csv` and `tables.json` (every row of every report plus the
/// three rendered tables) into `dir`.
pub fn write_tables(dir: &Path, models: &[(&str, &Report)]) -> Result<(), DataError> {
    write_tables_with_command(dir, models, None)
}

/// [`write_tables`], recording the invocation as `command_line` in tables.json and as a last
/// "Command:" line of tables.md (`depthsense report` shows it).
pub fn write_tables_with_command(
    dir: &Path,
    models: &[(&str, &Report)],
    command_line: Option<&str>,
) -> Result<(), DataError> {
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
    let mut doc = tables::report_doc(models);
    doc.command(command_line);
    let md = doc.to_markdown();
    let csv = tables::csv_report(models);
    let json_path = dir.join("tables.json");
    let record = TablesRecord::new(
        models,
        serde_json::to_value(tables::all_tables(models))
            .map_err(|e| DataError::encode(&json_path, e))?,
        command_line,
        &doc,
        &json_path,
    )
    .map_err(|e| DataError::Parse {
        path: e.path.clone(),
        reason: e.reason(),
    })?;
    let w = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        write_atomic(&p, bytes).map_err(|e| DataError::io(&p, e))
    };
    w("tables.md", md.as_bytes())?;
    w("tables.csv", csv.as_bytes())?;
    w(
        "tables.json",
        to_json_pretty(&record)
            .map_err(|e| DataError::encode(&json_path, e))?
            .as_bytes(),
    )
}
