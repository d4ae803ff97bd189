//! What a fuzz corpus is made of: inputs of one or more files, the repository's files they are
//! drawn from, and scratch folders to write them to.

use std::io;
use std::path::Path;

/// A set of files making up one input; the first is the one the loader opens, the others are
/// what it refers to (a map YAML's image). Names are relative to the scratch folder.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    pub files: Vec<(String, Vec<u8>)>,
}

/// `Scene` for a file starting (after `//` comments) with `Scene(`.
pub fn top_level_struct(text: &[u8]) -> Option<&str> {
    let text = std::str::from_utf8(text).ok()?;
    let code = text.lines().map(str::trim).find(|l| !l.is_empty() && !l.starts_with("//"))?;
    let name = &code[..code.find('(')?];
    (!name.is_empty()).then_some(name)
}

/// `root/folder/*.ron`, sorted by name, as `("folder/name.ron", bytes)`.
pub fn repo_files(root: &Path, folder: &str) -> io::Result<Vec<(String, Vec<u8>)>> {
    let dir = root.join(folder);
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .map_err(|e| {
            io::Error::new(
                e.kind(),
                format!("{}: {e} (run from the repository root or pass --root)", dir.display()),
            )
        })?
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".ron"))
        .collect();
    names.sort();
    names.into_iter().map(|n| Ok((format!("{folder}/{n}"), std::fs::read(dir.join(&n))?))).collect()
}

/// A fresh folder under the system's temporary directory.
pub fn tempfile_dir() -> io::Result<std::path::PathBuf> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let dir = std::env::temp_dir().join(format!(
        "apfn-fuzz-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}
