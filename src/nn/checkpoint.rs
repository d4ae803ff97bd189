//! Checkpoints as safetensors files (readable from Python): f32 tensors plus string metadata,
//! stored as F32 or, to ship a trained network at half the size, F16.
//! Weights, Adam moments, … of a [`Params`] arena go in as tensors named `prefix + spec.name`.
//! Files are written atomically (temp file in the same directory, fsync, rename).

use std::collections::{BTreeMap, HashMap};
use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use safetensors::Dtype;
use safetensors::tensor::{SafeTensorError, SafeTensors, View};

use crate::nn::params::Params;

/// One f32 tensor, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedTensor {
    pub name: String,
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// How a checkpoint's tensors are stored in the file; in memory they are f32 either way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Storage {
    /// IEEE single precision: every value bit for bit (training state, resume).
    #[default]
    F32,
    /// IEEE half precision: half the bytes, each value rounded to 11 significant bits (relative
    /// error ≤ 2⁻¹¹ from 6.1e-5 up to the largest half, 65,504; below, absolute ≤ 3e-8). For a
    /// trained network to ship.
    F16,
}

/// The contents of a checkpoint file. Tensors come back from [`Checkpoint::load`] in file order
/// (safetensors sorts them by name when writing).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Checkpoint {
    pub tensors: Vec<NamedTensor>,
    pub metadata: BTreeMap<String, String>,
    /// How [`Checkpoint::save`] writes the tensors; what [`Checkpoint::load`] found (F16 if any
    /// tensor was).
    pub storage: Storage,
    /// The file this was loaded from, for error messages (`None` when built in memory).
    pub source: Option<PathBuf>,
}

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("cannot {action} checkpoint {}: {source}", path.display())]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{} is not a valid safetensors file: {source}", path.display())]
    Format {
        path: PathBuf,
        #[source]
        source: SafeTensorError,
    },
    #[error("cannot encode checkpoint {}: {source}", path.display())]
    Encode {
        path: PathBuf,
        #[source]
        source: SafeTensorError,
    },
    #[error("tensor `{name}` in {} has dtype {dtype}, expected F32 or F16", path.display())]
    Dtype { path: PathBuf, name: String, dtype: String },
    #[error("tensor `{name}` for {} has shape {shape:?} ({expected} values) but {found} values", path.display())]
    DataLength { path: PathBuf, name: String, shape: Vec<usize>, expected: usize, found: usize },
    #[error("tensor name `{name}` appears twice in checkpoint {}", path.display())]
    Duplicate { path: PathBuf, name: String },
    #[error("tensor `{name}` is missing from checkpoint {}", path.display())]
    Missing { path: PathBuf, name: String },
    #[error("tensor `{name}` in {} has shape {found:?}, expected {expected:?}", path.display())]
    Shape { path: PathBuf, name: String, expected: Vec<usize>, found: Vec<usize> },
    #[error("tensor `{name}` in {} has non-finite value {value} at flat index {index}", path.display())]
    NonFinite { path: PathBuf, name: String, index: usize, value: f32 },
    #[error("tensor `{name}` for {} has value {value} at flat index {index}, beyond F16's ±65504", path.display())]
    HalfRange { path: PathBuf, name: String, index: usize, value: f32 },
}

/// Lets `safetensors::serialize` read a tensor as little-endian bytes of its storage without a
/// second copy held.
struct StoredView<'a>(&'a NamedTensor, Storage);

impl View for StoredView<'_> {
    fn dtype(&self) -> Dtype {
        match self.1 {
            Storage::F32 => Dtype::F32,
            Storage::F16 => Dtype::F16,
        }
    }
    fn shape(&self) -> &[usize] {
        &self.0.shape
    }
    fn data(&self) -> std::borrow::Cow<'_, [u8]> {
        let values = self.0.data.iter();
        match self.1 {
            Storage::F32 => values.flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>().into(),
            Storage::F16 => {
                values.flat_map(|&x| half::f16::from_f32(x).to_le_bytes()).collect::<Vec<u8>>().into()
            }
        }
    }
    fn data_len(&self) -> usize {
        self.0.data.len() * self.dtype().bitsize() / 8
    }
}

/// Deletes the temporary file unless the rename succeeded.
struct TempGuard(Option<PathBuf>);

impl Drop for TempGuard {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            let _ = fs::remove_file(p);
        }
    }
}

impl Checkpoint {
    /// Writes to a temporary file in the same directory, fsyncs, renames over `path`: a crash never leaves a half file.
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        let io = |action, source| CheckpointError::Io { path: path.to_path_buf(), action, source };
        let mut seen = std::collections::HashSet::new();
        for t in &self.tensors {
            let expected: usize = t.shape.iter().product();
            if expected != t.data.len() {
                return Err(CheckpointError::DataLength {
                    path: path.to_path_buf(),
                    name: t.name.clone(),
                    shape: t.shape.clone(),
                    expected,
                    found: t.data.len(),
                });
            }
            // safetensors would silently keep only one of two equal names.
            if !seen.insert(t.name.as_str()) {
                return Err(CheckpointError::Duplicate { path: path.to_path_buf(), name: t.name.clone() });
            }
            let beyond_half = |x: &f32| x.is_finite() && x.abs() > f32::from(half::f16::MAX);
            if self.storage == Storage::F16
                && let Some((index, &value)) = t.data.iter().enumerate().find(|(_, x)| beyond_half(x))
            {
                return Err(CheckpointError::HalfRange {
                    path: path.to_path_buf(),
                    name: t.name.clone(),
                    index,
                    value,
                });
            }
        }
        let metadata: Option<HashMap<String, String>> = (!self.metadata.is_empty())
            .then(|| self.metadata.iter().map(|(k, v)| (k.clone(), v.clone())).collect());
        let bytes = safetensors::serialize(
            self.tensors.iter().map(|t| (t.name.as_str(), StoredView(t, self.storage))),
            metadata,
        )
        .map_err(|source| CheckpointError::Encode { path: path.to_path_buf(), source })?;
        let bytes = canonical_header(bytes);

        let file_name = path.file_name().ok_or_else(|| {
            io("write", std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name"))
        })?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        // Same directory so the rename stays on one filesystem (atomic); unique per process and call.
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let tmp = dir.join(format!(
            ".{}.{}.{}.tmp",
            file_name.to_string_lossy(),
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let mut file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| io("create a temporary file for", e))?;
        let mut guard = TempGuard(Some(tmp.clone()));
        file.write_all(&bytes).map_err(|e| io("write", e))?;
        file.sync_all().map_err(|e| io("fsync", e))?;
        drop(file);
        fs::rename(&tmp, path).map_err(|e| io("rename the temporary file onto", e))?;
        guard.0 = None;
        // Persist the rename itself; some filesystems refuse to fsync a directory, which is harmless.
        if let Ok(d) = File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
    }

    /// Reads a safetensors file. F32 and F16 tensors; any other dtype is an error naming the tensor.
    pub fn load(path: &Path) -> Result<Self, CheckpointError> {
        let bytes = fs::read(path).map_err(|source| CheckpointError::Io {
            path: path.to_path_buf(),
            action: "read",
            source,
        })?;
        let format = |source| CheckpointError::Format { path: path.to_path_buf(), source };
        let (header_len, meta) = SafeTensors::read_metadata(&bytes).map_err(format)?;
        // read_metadata checked that the offsets tile the data section exactly.
        let data = &bytes[8 + header_len..];
        let (mut tensors, mut storage) = (Vec::new(), Storage::F32);
        for name in meta.offset_keys() {
            let info =
                meta.info(&name).ok_or_else(|| format(SafeTensorError::TensorNotFound(name.clone())))?;
            let (start, end) = info.data_offsets;
            // chunks + from_le_bytes: the data section need not be aligned.
            let bytes = &data[start..end];
            let values: Vec<f32> = match info.dtype {
                Dtype::F32 => {
                    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
                }
                Dtype::F16 => {
                    storage = Storage::F16;
                    bytes.chunks_exact(2).map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32()).collect()
                }
                dtype => {
                    return Err(CheckpointError::Dtype {
                        path: path.to_path_buf(),
                        name,
                        dtype: format!("{dtype:?}"),
                    });
                }
            };
            tensors.push(NamedTensor { name, shape: info.shape.clone(), data: values });
        }
        let metadata = meta.metadata().iter().flatten().map(|(k, v)| (k.clone(), v.clone())).collect();
        Ok(Self { tensors, metadata, storage, source: Some(path.to_path_buf()) })
    }

    /// Values in all the file's tensors: a loader refuses a configuration asking for more
    /// before it allocates the network.
    pub fn value_count(&self) -> u64 {
        self.tensors.iter().map(|t| t.data.len() as u64).sum()
    }

    /// The first tensor with this name.
    pub fn tensor(&self, name: &str) -> Option<&NamedTensor> {
        self.tensors.iter().find(|t| t.name == name)
    }

    /// Every parameter as a tensor (names and shapes from the specs), with a `prefix` ("" for the weights, e.g. "adam.m/" for moments).
    pub fn push_buffer(&mut self, params: &Params, buf: &[f32], prefix: &str) {
        for (id, spec) in params.specs() {
            self.tensors.push(NamedTensor {
                name: format!("{prefix}{}", spec.name),
                shape: spec.shape.clone(),
                data: params.of(buf, id).to_vec(),
            });
        }
    }

    /// Reads every parameter of `params` from tensors named prefix+name into `buf` (laid out like params).
    /// Everything is checked before anything is written, so `buf` is untouched on error.
    pub fn read_buffer(&self, params: &Params, buf: &mut [f32], prefix: &str) -> Result<(), CheckpointError> {
        assert_eq!(buf.len(), params.len(), "read_buffer: buffer is not laid out like the parameter arena");
        let path = || self.source.clone().unwrap_or_else(|| PathBuf::from("<checkpoint in memory>"));
        let mut found = Vec::with_capacity(params.specs().count());
        for (id, spec) in params.specs() {
            let name = format!("{prefix}{}", spec.name);
            let Some(t) = self.tensor(&name) else {
                return Err(CheckpointError::Missing { path: path(), name });
            };
            if t.shape != spec.shape {
                let (expected, found) = (spec.shape.clone(), t.shape.clone());
                return Err(CheckpointError::Shape { path: path(), name, expected, found });
            }
            if let Some((index, &value)) = t.data.iter().enumerate().find(|(_, x)| !x.is_finite()) {
                return Err(CheckpointError::NonFinite { path: path(), name, index, value });
            }
            found.push((id, t));
        }
        for (id, t) in found {
            buf[params.range(id)].copy_from_slice(&t.data);
        }
        Ok(())
    }
}

/// The same file with its JSON header's keys sorted: safetensors writes the metadata from a
/// `HashMap`, whose order changes from run to run, and the same state must give the same bytes
/// (resumed training is checked byte for byte). Offsets are relative to the data section, so
/// only the header (padded with spaces to 8 bytes, as safetensors does) changes.
fn canonical_header(bytes: Vec<u8>) -> Vec<u8> {
    type Header = std::collections::BTreeMap<String, serde_json::Value>;
    let len = u64::from_le_bytes(bytes[..8].try_into().expect("8 length bytes")) as usize;
    let mut header: Header =
        serde_json::from_slice(&bytes[8..8 + len]).expect("safetensors wrote valid JSON");
    if let Some(meta) = header.get_mut("__metadata__") {
        let sorted: std::collections::BTreeMap<String, String> =
            serde_json::from_value(meta.take()).expect("metadata maps strings to strings");
        *meta = serde_json::to_value(sorted).expect("strings serialise");
    }
    let mut json = serde_json::to_vec(&header).expect("a JSON value serialises");
    json.resize(json.len().div_ceil(8) * 8, b' ');
    let mut out = Vec::with_capacity(8 + json.len() + bytes.len() - 8 - len);
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend_from_slice(&bytes[8 + len..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Checkpoint {
        let mut ck = Checkpoint::default();
        // Unsorted names and awkward values: the round trip must be bit-exact.
        ck.tensors.push(NamedTensor {
            name: "z/kernel".into(),
            shape: vec![2, 3],
            data: vec![1.0, -0.0, f32::MIN_POSITIVE / 4.0, f32::MAX, 1.0 / 3.0, -7.5],
        });
        ck.tensors.push(NamedTensor { name: "a/bias".into(), shape: vec![3], data: vec![0.1, 0.2, 0.3] });
        ck.tensors.push(NamedTensor { name: "scalar".into(), shape: vec![], data: vec![42.0] });
        ck.metadata.insert("step".into(), "1234".into());
        ck.metadata.insert("config".into(), r#"{"lr": 0.001}"#.into());
        ck
    }

    fn sorted(mut t: Vec<NamedTensor>) -> Vec<NamedTensor> {
        t.sort_by(|a, b| a.name.cmp(&b.name));
        t
    }

    fn bits(t: &[NamedTensor]) -> Vec<(String, Vec<usize>, Vec<u32>)> {
        t.iter()
            .map(|t| (t.name.clone(), t.shape.clone(), t.data.iter().map(|x| x.to_bits()).collect()))
            .collect()
    }

    fn dir_entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<_> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn same_checkpoint_gives_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let mut ck = sample();
        for k in 0..12 {
            ck.metadata.insert(format!("key{k}"), k.to_string()); // enough keys to expose a hash order
        }
        let files: Vec<Vec<u8>> = (0..4)
            .map(|i| {
                let path = dir.path().join(format!("{i}.safetensors"));
                ck.clone().save(&path).unwrap();
                fs::read(&path).unwrap()
            })
            .collect();
        assert!(files.windows(2).all(|w| w[0] == w[1]), "saving one state twice must write the same bytes");
        assert_eq!(Checkpoint::load(&dir.path().join("0.safetensors")).unwrap().metadata, ck.metadata);
    }

    #[test]
    fn round_trip_bit_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ck.safetensors");
        let ck = sample();
        ck.save(&path).unwrap();
        let back = Checkpoint::load(&path).unwrap();
        assert_eq!(bits(&back.tensors), bits(&sorted(ck.tensors.clone())));
        assert_eq!(back.metadata, ck.metadata);
        assert_eq!(back.source.as_deref(), Some(path.as_path()));
        assert_eq!(back.tensor("scalar").unwrap().data, vec![42.0]);
        assert!(back.tensor("nope").is_none());

        // No metadata at all is also fine.
        let empty = Checkpoint::default();
        empty.save(&path).unwrap();
        let back = Checkpoint::load(&path).unwrap();
        assert!(back.tensors.is_empty() && back.metadata.is_empty());
    }

    /// F16 storage writes two bytes a value and reads back each value rounded to half precision;
    /// a value beyond half's range is refused by name before anything is written.
    #[test]
    fn half_storage_rounds_each_value_and_refuses_overflow() {
        let dir = tempfile::tempdir().unwrap();
        let (full, small) = (dir.path().join("full.safetensors"), dir.path().join("half.safetensors"));
        let mut ck = sample();
        ck.tensors[0].data[3] = 60000.0; // f32::MAX has no half
        ck.save(&full).unwrap();
        let half_ck = Checkpoint { storage: Storage::F16, ..ck.clone() };
        half_ck.save(&small).unwrap();
        let data_bytes = |path: &Path| {
            fs::metadata(path).unwrap().len()
                - 8
                - SafeTensors::read_metadata(&fs::read(path).unwrap()).unwrap().0 as u64
        };
        assert_eq!(2 * data_bytes(&small), data_bytes(&full), "two bytes a value");
        let back = Checkpoint::load(&small).unwrap();
        assert_eq!(back.storage, Storage::F16);
        let rounded: Vec<NamedTensor> = sorted(ck.tensors.clone())
            .into_iter()
            .map(|t| NamedTensor {
                data: t.data.iter().map(|&x| half::f16::from_f32(x).to_f32()).collect(),
                ..t
            })
            .collect();
        assert_eq!(bits(&back.tensors), bits(&rounded));
        let third = back.tensor("z/kernel").unwrap().data[4];
        assert!(third != 1.0 / 3.0 && (third - 1.0 / 3.0).abs() <= (1.0 / 3.0) / 2048.0, "{third}");
        assert_eq!(Checkpoint::load(&full).unwrap().storage, Storage::F32);

        let mut too_big = half_ck;
        too_big.tensors[1].data[2] = 70000.0;
        let err = too_big.save(&small).unwrap_err().to_string();
        assert!(err.contains("`a/bias`") && err.contains("70000") && err.contains("F16"), "{err}");
        assert_eq!(bits(&Checkpoint::load(&small).unwrap().tensors), bits(&rounded), "the file kept");
    }

    #[test]
    fn save_is_atomic() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ck.safetensors");
        fs::write(&path, vec![b'x'; 100_000]).unwrap();
        sample().save(&path).unwrap();
        assert_eq!(dir_entries(dir.path()), vec!["ck.safetensors"], "no temp file left behind");
        assert_eq!(bits(&Checkpoint::load(&path).unwrap().tensors), bits(&sorted(sample().tensors)));

        // A smaller checkpoint replaces a bigger one whole (no tail of the old file).
        let mut small = Checkpoint::default();
        small.tensors.push(NamedTensor { name: "w".into(), shape: vec![1], data: vec![1.0] });
        small.save(&path).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap().tensors, small.tensors);
        assert_eq!(dir_entries(dir.path()), vec!["ck.safetensors"]);

        // An invalid checkpoint fails before touching the existing file.
        let mut bad = small.clone();
        bad.tensors.push(NamedTensor { name: "w".into(), shape: vec![1], data: vec![2.0] });
        let err = bad.save(&path).unwrap_err().to_string();
        assert!(err.contains("appears twice") && err.contains("ck.safetensors"), "{err}");
        bad.tensors[1] = NamedTensor { name: "v".into(), shape: vec![2], data: vec![2.0] };
        let err = bad.save(&path).unwrap_err().to_string();
        assert!(err.contains("`v`") && err.contains("1 values"), "{err}");
        assert_eq!(Checkpoint::load(&path).unwrap().tensors, small.tensors);
        assert_eq!(dir_entries(dir.path()), vec!["ck.safetensors"]);
    }

    #[test]
    fn save_into_missing_directory_names_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no_such_dir").join("ck.safetensors");
        let err = sample().save(&path).unwrap_err();
        assert!(matches!(err, CheckpointError::Io { .. }), "{err:?}");
        assert!(err.to_string().contains(&path.display().to_string()), "{err}");
    }

    #[test]
    fn load_errors() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.safetensors");
        let err = Checkpoint::load(&missing).unwrap_err().to_string();
        assert!(err.contains("cannot read") && err.contains("missing.safetensors"), "{err}");

        let junk = dir.path().join("junk.safetensors");
        fs::write(&junk, "this is a text file, not tensors\n").unwrap();
        let err = Checkpoint::load(&junk).unwrap_err();
        assert!(matches!(err, CheckpointError::Format { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(msg.contains("junk.safetensors") && msg.contains("not a valid safetensors file"), "{msg}");

        // A valid safetensors file with an f64 tensor.
        let f64_bytes: Vec<u8> = [1.0f64, 2.0].iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = safetensors::tensor::TensorView::new(Dtype::F64, vec![2], &f64_bytes).unwrap();
        let bytes = safetensors::serialize([("double", view)], None).unwrap();
        let f64_path = dir.path().join("f64.safetensors");
        fs::write(&f64_path, bytes).unwrap();
        let err = Checkpoint::load(&f64_path).unwrap_err().to_string();
        assert!(err.contains("`double`") && err.contains("F64") && err.contains("f64.safetensors"), "{err}");
    }

    #[test]
    fn buffers_round_trip_and_read_buffer_errors() {
        let mut params = Params::new();
        let w = params.add("dense/kernel", &[2, 2]);
        params.add("dense/bias", &[2]);
        params.values.copy_from_slice(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let moments: Vec<f32> = (0..6).map(|i| i as f32 * 0.5).collect();

        let mut ck = Checkpoint::default();
        ck.push_buffer(&params, &params.values, "");
        ck.push_buffer(&params, &moments, "adam.m/");
        assert_eq!(ck.tensor("adam.m/dense/bias").unwrap().shape, vec![2]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.safetensors");
        ck.save(&path).unwrap();
        let ck = Checkpoint::load(&path).unwrap();

        let mut values = vec![0.0; 6];
        ck.read_buffer(&params, &mut values, "").unwrap();
        assert_eq!(values, params.values);
        let mut m = vec![0.0; 6];
        ck.read_buffer(&params, &mut m, "adam.m/").unwrap();
        assert_eq!(m, moments);

        let check = |ck: &Checkpoint, prefix: &str, needles: &[&str]| {
            let mut buf = vec![-1.0; 6];
            let err = ck.read_buffer(&params, &mut buf, prefix).unwrap_err().to_string();
            for n in needles {
                assert!(err.contains(n), "`{err}` should mention `{n}`");
            }
            assert_eq!(buf, vec![-1.0; 6], "buffer untouched on error");
        };
        check(&ck, "adam.v/", &["model.safetensors", "`adam.v/dense/kernel`", "missing"]);

        let mut wrong = ck.clone();
        wrong.tensors.iter_mut().find(|t| t.name == "dense/bias").unwrap().shape = vec![1, 2];
        check(&wrong, "", &["model.safetensors", "`dense/bias`", "[1, 2]", "expected [2]"]);

        let mut nan = ck.clone();
        nan.tensors.iter_mut().find(|t| t.name == "adam.m/dense/kernel").unwrap().data[3] = f32::NAN;
        check(&nan, "adam.m/", &["model.safetensors", "`adam.m/dense/kernel`", "NaN", "index 3"]);

        // Built in memory: still a readable error.
        let mut mem = Checkpoint::default();
        mem.push_buffer(&params, &params.values, "");
        mem.tensors[0].data[0] = f32::INFINITY;
        check(&mem, "", &["<checkpoint in memory>", "`dense/kernel`", "index 0"]);
        assert_eq!(params.find("dense/kernel"), Some(w));
    }

    #[test]
    fn loads_pfnet_oracle_weights() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/reference/pfnet_oracle/weights.safetensors"
        ));
        if !path.exists() {
            eprintln!("skipping: {} not present", path.display());
            return;
        }
        let ck = Checkpoint::load(path).unwrap();
        assert_eq!(ck.tensors.len(), 38);
        assert_eq!(ck.tensor("m_c3/kernel").expect("m_c3/kernel").shape, vec![3, 3, 1, 24]);
        for t in &ck.tensors {
            assert_eq!(t.data.len(), t.shape.iter().product::<usize>(), "{}", t.name);
            assert!(t.data.iter().all(|x| x.is_finite()), "{}", t.name);
        }
    }
}
