//! Writes evaluation results: results.json (rows), results.csv, results.md laid out like the
//! paper's tables (rows = policies, column groups = tasks, one column per split), episodes.csv
//! (every episode behind every row), steps.csv (each row's error at every step) and paired.md
//! (each policy against its cell's best other).

use crate::eval::episodes::EpisodeRow;
use crate::eval::paired::{paired_markdown, paired_rows};
use crate::eval::row::ResultRow;
use crate::eval::steps::StepRow;
use crate::world::map::write_atomically;
use anyhow::Context;
use serde::Serialize;
use std::path::Path;

/// Writes the six result files atomically into `out`.
pub fn write_results(
    out: &Path,
    rows: &[ResultRow],
    episodes: &[EpisodeRow],
    steps: &[StepRow],
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_atomically(&out.join("results.json"), serde_json::to_string_pretty(rows)?.as_bytes())?;
    write_atomically(&out.join("results.csv"), &csv(rows)?)?;
    write_atomically(&out.join("results.md"), markdown(rows).as_bytes())?;
    write_atomically(&out.join("episodes.csv"), &csv(episodes)?)?;
    write_atomically(&out.join("steps.csv"), &csv(steps)?)?;
    write_atomically(&out.join("paired.md"), paired_markdown(&paired_rows(episodes)).as_bytes())?;
    Ok(())
}

/// A header from `T`'s field names, then one line per record.
pub fn csv<T: Serialize>(records: &[T]) -> anyhow::Result<Vec<u8>> {
    let mut writer = csv::Writer::from_writer(Vec::new());
    for record in records {
        writer.serialize(record)?;
    }
    Ok(writer.into_inner()?)
}

/// The distinct `items` in the order they first appear: rows, columns and lines follow the
/// config's order, not a sort.
pub fn first_seen<T: PartialEq>(items: impl IntoIterator<Item = T>) -> Vec<T> {
    let mut seen = Vec::new();
    for item in items {
        if !seen.contains(&item) {
            seen.push(item);
        }
    }
    seen
}

/// One table per localizer: each cell "mean pos cm / mean orient rad (success %)"; a policy row
/// appears under a localizer only if that localizer ran it (missing task/split cells read "–").
pub fn markdown(rows: &[ResultRow]) -> String {
    let unique = |f: &dyn Fn(&ResultRow) -> String| first_seen(rows.iter().map(f));
    let tasks = unique(&|r| r.task.name().to_owned());
    let splits = unique(&|r| r.split.clone());
    let mut text = String::from(
        "Each cell: mean position error (cm) / mean |orientation error| (rad) over all steps of all \
         episodes (the paper's \"RMSE\"), then the success rate.\n",
    );
    for localizer in unique(&|r| r.localizer.clone()) {
        text += &format!("\n### localizer: {localizer}\n\n| policy |");
        for task in &tasks {
            for split in &splits {
                text += &format!(" {task} · {split} |");
            }
        }
        text += &format!("\n|---|{}\n", "---|".repeat(tasks.len() * splits.len()));
        for policy in unique(&|r| r.policy.clone()) {
            if !rows.iter().any(|r| r.localizer == localizer && r.policy == policy) {
                continue;
            }
            text += &format!("| {policy} |");
            for task in &tasks {
                for split in &splits {
                    let cell = rows.iter().find(|r| {
                        r.localizer == localizer
                            && r.policy == policy
                            && r.task.name() == task
                            && &r.split == split
                    });
                    text += &match cell {
                        Some(r) => format!(
                            " {:.1} / {:.2} ({:.0} %) |",
                            r.mean_pos_err_m * 100.0,
                            r.mean_orient_err_rad,
                            r.success_rate * 100.0
                        ),
                        None => " – |".to_owned(),
                    };
                }
            }
            text.push('\n');
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::particles::Task;

    #[test]
    fn csv_has_the_json_keys_as_header_and_quotes_commas() {
        let mut r = row("mcl", "turn", Task::SemiGlobal);
        r.map = "maps/a,b.yaml".into();
        let text = String::from_utf8(csv(&[r]).expect("encodes")).expect("utf-8");
        let mut lines = text.lines();
        assert!(lines.next().expect("header").starts_with("localizer,policy,task,split,map,particles,"));
        assert!(
            lines.next().expect("row").starts_with("mcl,turn,semi_global,seen,\"maps/a,b.yaml\",300,"),
            "{text}"
        );
    }

    fn row(localizer: &str, policy: &str, task: Task) -> ResultRow {
        ResultRow {
            localizer: localizer.into(),
            policy: policy.into(),
            task,
            split: "seen".into(),
            map: "apartments 0..4".into(),
            particles: 300,
            episodes: 20,
            seed: 1,
            mean_pos_err_m: 0.1,
            rmse_pos_m: 0.2,
            final_pos_err_m: 0.1,
            mean_orient_err_rad: 0.02,
            final_orient_err_rad: 0.02,
            success_rate: 1.0,
        }
    }

    #[test]
    fn markdown_lists_only_policies_a_localizer_ran() {
        let rows = [
            row("mcl", "random (a)", Task::Tracking),
            row("mcl", "random (b)", Task::Tracking),
            row("mcl_beam", "random", Task::Tracking),
            row("mcl_beam", "random", Task::Global),
        ];
        let text = markdown(&rows);
        let (mcl, beam) = text.split_once("### localizer: mcl_beam").expect("one table per localizer");
        assert!(mcl.contains("| random (a) |") && !mcl.contains("| random |"), "mcl table:\n{mcl}");
        assert!(beam.contains("| random |") && !beam.contains("random (a)"), "mcl_beam table:\n{beam}");
        assert!(mcl.contains(" – |"), "a task the localizer did not run still reads –:\n{mcl}");
    }
}
