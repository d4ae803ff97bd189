//! Runs one target: input `i` of seed `s` is the mutation drawn from the stream (s, target, i),
//! written to a scratch folder and loaded on a worker thread under `catch_unwind`. Each input
//! ends as ok, a clean error, a panic, or slow (over the time budget); an input still running
//! after [`HANG_FACTOR`] budgets is a hang and ends the target's run (its thread cannot be
//! stopped). Time is the worker thread's CPU time where Linux reports it, so a busy machine does
//! not turn slow inputs into hangs; elsewhere it is wall-clock. Panicking, slow and hanging inputs
//! are saved for reproduction.

use crate::fuzz::mutate::{corpus_words, mutate};
use crate::fuzz::sample::{Sample, tempfile_dir};
use crate::fuzz::targets::{Target, context};
use crate::world::rng::stream;
use rand::Rng;
use std::cell::{Cell, RefCell};
use std::io;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Once;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// An input still running after this many time budgets is reported as a hang.
pub const HANG_FACTOR: u32 = 60;

/// Stack of the worker thread: the main thread's 8 MiB, so recursion limits are tested as the
/// CLI meets them.
const WORKER_STACK: usize = 8 << 20;

/// How a run is set up.
#[derive(Clone, Debug)]
pub struct FuzzOptions {
    /// Inputs per target.
    pub inputs: u64,
    /// Root of every mutation: the same seed gives the same inputs.
    pub seed: u64,
    /// Time an input may take before it counts as slow.
    pub budget: Duration,
    /// The repository (its `scenes/` and `systems/` hold the seed files).
    pub root: PathBuf,
    /// Where panicking, slow and hanging inputs are saved (one folder each).
    pub findings: Option<PathBuf>,
}

/// What happened to the inputs of one target.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TargetReport {
    pub target: &'static str,
    pub inputs: u64,
    pub ok: u64,
    pub clean_errors: u64,
    pub panics: u64,
    pub slow: u64,
    pub hangs: u64,
    pub slowest: Duration,
    pub wall: Duration,
    /// One line per panic, slow input or hang: index, message, saved folder.
    pub findings: Vec<String>,
}

/// How one input ended.
enum Outcome {
    Ok,
    CleanError,
    Panic(String),
}

thread_local! {
    /// Set on fuzz workers: their panics are expected, recorded and not printed.
    static QUIET_PANICS: Cell<bool> = const { Cell::new(false) };
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Installs (once) a panic hook that records a fuzz worker's panic with its location instead of
/// printing it, and leaves every other thread's panics to the previous hook.
fn install_panic_hook() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if QUIET_PANICS.with(Cell::get) {
                LAST_PANIC.with(|p| *p.borrow_mut() = Some(info.to_string()));
            } else {
                previous(info);
            }
        }));
    });
}

/// Fuzzes `target` with `options.inputs` mutated inputs.
pub fn fuzz_target(target: &'static Target, options: &FuzzOptions) -> io::Result<TargetReport> {
    install_panic_hook();
    let started = Instant::now();
    let corpus = (target.corpus)(&options.root)?;
    let scratch = tempfile_dir()?;
    write_files(&scratch, &context(&options.root)?)?;
    let index = crate::fuzz::TARGETS.iter().position(|t| std::ptr::eq(t, target)).unwrap_or(usize::MAX);
    let mut report = TargetReport { target: target.name, ..Default::default() };
    let result = run_inputs(target, &corpus, &scratch, index as u64, options, &mut report);
    std::fs::remove_dir_all(&scratch)?;
    report.wall = started.elapsed();
    result.map(|()| report)
}

/// The input loop: the main thread mutates and watches the clock, a worker loads.
fn run_inputs(
    target: &'static Target,
    corpus: &[Sample],
    scratch: &Path,
    target_key: u64,
    options: &FuzzOptions,
    report: &mut TargetReport,
) -> io::Result<()> {
    let all_files: Vec<&[u8]> = corpus.iter().flat_map(|s| s.files.iter().map(|f| f.1.as_slice())).collect();
    let words = corpus_words(&all_files);
    let (to_worker, inbox) = mpsc::channel::<PathBuf>();
    let (outbox, from_worker) = mpsc::channel::<(Outcome, Duration)>();
    let (clock_out, clock_in) = mpsc::channel::<WorkerClock>();
    let worker = move || {
        QUIET_PANICS.with(|q| q.set(true));
        let clock = WorkerClock::current();
        let _ = clock_out.send(clock.clone());
        for entry in inbox {
            let started = clock.now();
            let outcome = match catch_unwind(AssertUnwindSafe(|| (target.load)(&entry))) {
                Ok(Ok(())) => Outcome::Ok,
                Ok(Err(_)) => Outcome::CleanError,
                Err(payload) => Outcome::Panic(panic_message(payload.as_ref())),
            };
            if outbox.send((outcome, clock.now().saturating_sub(started))).is_err() {
                break;
            }
        }
    };
    std::thread::Builder::new()
        .name(format!("fuzz-{}", target.name))
        .stack_size(WORKER_STACK)
        .spawn(worker)?;
    let clock = clock_in.recv().map_err(io::Error::other)?;
    let hang_after = options.budget * HANG_FACTOR;
    let mut previous: Vec<String> = Vec::new();
    for i in 0..options.inputs {
        let mut rng = stream(&[options.seed, target_key, i]);
        let input = mutated(corpus, &all_files, &words, &mut rng);
        // The last input's files go, so that every input is exactly what a saved finding holds.
        for name in previous.drain(..) {
            std::fs::remove_file(scratch.join(name))?;
        }
        write_files(scratch, &input.files)?;
        previous.extend(input.files.iter().map(|f| f.0.clone()));
        let sent = clock.now();
        to_worker.send(scratch.join(&input.files[0].0)).map_err(io::Error::other)?;
        report.inputs += 1;
        let answer = loop {
            match from_worker.recv_timeout(options.budget) {
                Ok(answer) => break Some(answer),
                Err(_) if clock.now().saturating_sub(sent) < hang_after => continue,
                Err(_) => break None,
            }
        };
        let Some((outcome, took)) = answer else {
            report.hangs += 1;
            let saved = save(options, target.name, i, &input, "hang")?;
            report.findings.push(format!("input {i}: still running after {hang_after:?} (a hang){saved}"));
            return Ok(());
        };
        report.slowest = report.slowest.max(took);
        match outcome {
            Outcome::Ok => report.ok += 1,
            Outcome::CleanError => report.clean_errors += 1,
            Outcome::Panic(message) => {
                report.panics += 1;
                let saved = save(options, target.name, i, &input, &message)?;
                report.findings.push(format!("input {i}: panic: {message}{saved}"));
            }
        }
        if took > options.budget {
            report.slow += 1;
            let saved = save(options, target.name, i, &input, &format!("took {took:?}"))?;
            report.findings.push(format!("input {i}: slow, {took:.2?}{saved}"));
        }
    }
    Ok(())
}

/// The worker thread's clock: its CPU time from `/proc/<pid>/task/<tid>/schedstat` when Linux
/// has it (readable from any thread), else wall-clock time.
#[derive(Clone)]
struct WorkerClock {
    schedstat: Option<PathBuf>,
    wall: Instant,
}

impl WorkerClock {
    /// The calling thread's clock.
    fn current() -> Self {
        let schedstat = std::fs::read_link("/proc/thread-self")
            .ok()
            .map(|task| Path::new("/proc").join(task).join("schedstat"))
            .filter(|path| cpu_time(path).is_some());
        WorkerClock { schedstat, wall: Instant::now() }
    }

    fn now(&self) -> Duration {
        self.schedstat.as_deref().and_then(cpu_time).unwrap_or_else(|| self.wall.elapsed())
    }
}

/// The first field of a schedstat file: nanoseconds on the CPU.
fn cpu_time(schedstat: &Path) -> Option<Duration> {
    let text = std::fs::read_to_string(schedstat).ok()?;
    text.split_whitespace().next()?.parse().ok().map(Duration::from_nanos)
}

/// One corpus sample with one of its files mutated (usually the entry file).
fn mutated(corpus: &[Sample], all_files: &[&[u8]], words: &[Vec<u8>], rng: &mut impl Rng) -> Sample {
    let mut sample = corpus[rng.random_range(0..corpus.len())].clone();
    let k = if rng.random_bool(0.75) { 0 } else { rng.random_range(0..sample.files.len()) };
    sample.files[k].1 = mutate(&sample.files[k].1, all_files, words, rng);
    sample
}

/// Writes `files` under `dir`, creating folders.
fn write_files(dir: &Path, files: &[(String, Vec<u8>)]) -> io::Result<()> {
    for (name, bytes) in files {
        let path = dir.join(name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(path, bytes)?;
    }
    Ok(())
}

/// Saves a finding's files and `what` under `findings/<target>-<index>/`; returns the text to
/// append to its report line.
fn save(options: &FuzzOptions, target: &str, index: u64, input: &Sample, what: &str) -> io::Result<String> {
    let Some(root) = &options.findings else { return Ok(String::new()) };
    let dir = root.join(format!("{target}-{index}"));
    write_files(&dir, &input.files)?;
    std::fs::write(dir.join("finding.txt"), format!("seed {} input {index}: {what}\n", options.seed))?;
    Ok(format!(" (saved to {})", dir.display()))
}

/// The panic's message with its location, as recorded by the hook, else the payload's text.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    LAST_PANIC.with(|p| p.borrow_mut().take()).unwrap_or_else(|| {
        payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".into())
    })
}
