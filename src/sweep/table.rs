//! Writes a merged sweep: sweep.json (rows), sweep.csv (one `_mean` and one `_ci95` column per
//! error metric, the success rate with its Wilson bounds) and sweep.md (one line per cell,
//! "mean ± half-width", success "rate (low–high)").

use crate::sweep::error::SweepError;
use crate::sweep::merge::SweepRow;
use crate::sweep::stats::MeanCi;
use crate::world::map::write_atomically;
use std::path::Path;

/// The metrics of a row, with their column names, in table order.
fn metrics(r: &SweepRow) -> [(&'static str, MeanCi); 5] {
    [
        ("mean_pos_err_m", r.mean_pos_err_m),
        ("rmse_pos_m", r.rmse_pos_m),
        ("final_pos_err_m", r.final_pos_err_m),
        ("mean_orient_err_rad", r.mean_orient_err_rad),
        ("final_orient_err_rad", r.final_orient_err_rad),
    ]
}

/// Writes the three files atomically into `out`.
pub fn write_sweep(out: &Path, rows: &[SweepRow]) -> Result<(), SweepError> {
    std::fs::create_dir_all(out).map_err(|source| SweepError::CreateDir { path: out.to_owned(), source })?;
    let json = serde_json::to_string_pretty(rows).map_err(|e| SweepError::JobFile {
        path: out.join("sweep.json"),
        message: format!("cannot encode the merged rows: {e}"),
    })?;
    write_atomically(&out.join("sweep.json"), json.as_bytes())?;
    let table = csv(rows).map_err(|e| SweepError::JobFile {
        path: out.join("sweep.csv"),
        message: format!("cannot encode the merged rows: {e}"),
    })?;
    write_atomically(&out.join("sweep.csv"), &table)?;
    write_atomically(&out.join("sweep.md"), markdown(rows).as_bytes())?;
    Ok(())
}

/// One line per cell; an interval is empty with a single seed.
pub fn csv(rows: &[SweepRow]) -> Result<Vec<u8>, csv::Error> {
    let mut writer = csv::Writer::from_writer(Vec::new());
    let mut header: Vec<String> =
        ["schedule", "localizer", "policy", "task", "split", "map", "particles", "episodes", "n", "seeds"]
            .map(String::from)
            .into();
    if let Some(r) = rows.first() {
        header
            .extend(metrics(r).iter().flat_map(|(name, _)| [format!("{name}_mean"), format!("{name}_ci95")]));
    }
    header.extend(["success_rate", "success_low95", "success_high95", "wall_s"].map(String::from));
    writer.write_record(&header)?;
    for r in rows {
        let seeds: Vec<String> = r.seeds.iter().map(u64::to_string).collect();
        let mut record = vec![
            r.schedule.clone(),
            r.localizer.clone(),
            r.policy.clone(),
            r.task.name().to_owned(),
            r.split.clone(),
            r.map.clone(),
            r.particles.to_string(),
            r.episodes.to_string(),
            r.n.to_string(),
            seeds.join(" "),
        ];
        for (_, m) in metrics(r) {
            record.push(format!("{:.5}", m.mean));
            record.push(m.ci95.map_or(String::new(), |c| format!("{c:.5}")));
        }
        let s = r.success;
        record.extend([s.rate, s.low95, s.high95].map(|x| format!("{x:.5}")));
        record.push(format!("{:.1}", r.wall_s));
        writer.write_record(&record)?;
    }
    writer.into_inner().map_err(|e| e.into_error().into())
}

/// "mean ± half-width" scaled by `scale`, or just the mean with one seed.
fn cell(m: MeanCi, scale: f64, decimals: usize) -> String {
    match m.ci95 {
        Some(ci) => format!("{:.*} ± {:.*}", decimals, m.mean * scale, decimals, ci * scale),
        None => format!("{:.*}", decimals, m.mean * scale),
    }
}

pub fn markdown(rows: &[SweepRow]) -> String {
    let mut text = String::from(
        "Errors: mean across seeds ± half-width of its 95 % confidence interval (Student t, n − 1 \
         degrees of freedom), each seed's error averaged over all steps of all episodes. Success: \
         the rate over all episodes of all seeds, with its 95 % Wilson interval.\n\n\
         | schedule | localizer | policy | task | split | n | pos err (cm) | final pos err (cm) | \
         orient err (rad) | success (95 % CI) |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        text += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.schedule,
            r.localizer,
            r.policy,
            r.task.name(),
            r.split,
            r.n,
            cell(r.mean_pos_err_m, 100.0, 1),
            cell(r.final_pos_err_m, 100.0, 1),
            cell(r.mean_orient_err_rad, 1.0, 3),
            r.success.percent(),
        );
    }
    text
}
