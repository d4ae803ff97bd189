//! Paths written inside a config file are relative to that file (as map_server resolves a map
//! YAML's image); they are joined here and tidied, so messages print `results/x`, not
//! `scenes/../results/x`.

use std::path::{Component, Path, PathBuf};

/// `relative` as seen from the folder holding `file` (unchanged if it is absolute), tidied.
pub fn relative_to_file(file: &Path, relative: &Path) -> PathBuf {
    tidy(&file.parent().unwrap_or(Path::new("")).join(relative))
}

/// Removes `.` and folds `dir/..` without touching the file system (symbolic links are not
/// followed, so `a/link/..` becomes `a`; config paths do not rely on that). Leading `..` stay.
pub fn tidy(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for part in path.components() {
        match part {
            Component::CurDir => {}
            Component::ParentDir => match out.components().next_back() {
                Some(Component::Normal(_)) => {
                    out.pop();
                }
                Some(Component::RootDir | Component::Prefix(_)) => {}
                _ => out.push(".."),
            },
            other => out.push(other),
        }
    }
    if out.as_os_str().is_empty() { PathBuf::from(".") } else { out }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tidy_folds_parent_steps_and_keeps_leading_ones() {
        let cases = [
            ("scenes/../results/x", "results/x"),
            ("./scenes/./a.ron", "scenes/a.ron"),
            ("scenes/../../shared/maps/m.yaml", "../shared/maps/m.yaml"),
            ("/work/a/../b", "/work/b"),
            ("/..", "/"),
            ("a/..", "."),
        ];
        for (given, want) in cases {
            assert_eq!(tidy(Path::new(given)), PathBuf::from(want), "tidy({given})");
        }
    }

    #[test]
    fn relative_to_file_resolves_against_the_files_folder() {
        let p = relative_to_file(Path::new("scenes/eval.ron"), Path::new("../systems/turn.ron"));
        assert_eq!(p, PathBuf::from("systems/turn.ron"));
        let abs = relative_to_file(Path::new("scenes/eval.ron"), Path::new("/maps/m.yaml"));
        assert_eq!(abs, PathBuf::from("/maps/m.yaml"), "absolute paths are kept");
        assert_eq!(relative_to_file(Path::new("eval.ron"), Path::new("x.yaml")), PathBuf::from("x.yaml"));
    }
}
