//! Progress bars for the long commands. On a terminal the bar is drawn in place; where stderr is
//! not one (a run under `nohup`, a CI log) indicatif would hide it, so the same figures are
//! written there as one plain line a minute instead: a log then shows how far a run is and how
//! long it has left, and a run shorter than a minute writes nothing extra.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle, TermLike};
use std::fmt;
use std::io::{self, IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How often a log gets a progress line.
const LOG_EVERY: Duration = Duration::from_secs(60);

/// A bar of `len` units drawn with `template` (indicatif's syntax) on a terminal, logged a line
/// a minute elsewhere.
pub fn progress_bar(len: u64, template: &str) -> ProgressBar {
    if io::stderr().is_terminal() {
        return ProgressBar::new(len).with_style(style(template));
    }
    let target = ProgressDrawTarget::term_like(Box::new(LogLines::new(io::stderr(), LOG_EVERY)));
    ProgressBar::with_draw_target(Some(len), target).with_style(style(&log_template(template)))
}

fn style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template).expect("static progress template")
}

/// `template` for a log line: the bar itself dropped (a log cannot redraw it), the time elapsed
/// in front.
fn log_template(template: &str) -> String {
    let figures: Vec<&str> = template.split(' ').filter(|part| !part.starts_with("{bar")).collect();
    format!("[{{elapsed_precise}}] {}", figures.join(" "))
}

/// A terminal stand-in that writes each drawn line to `out` at most once per `every` (the first
/// one `every` after it is made) and ignores cursor moves, which a log cannot follow.
struct LogLines<W> {
    out: Mutex<W>,
    every: Duration,
    last: Mutex<Instant>,
}

impl<W> LogLines<W> {
    fn new(out: W, every: Duration) -> Self {
        Self { out: Mutex::new(out), every, last: Mutex::new(Instant::now()) }
    }
}

impl<W> fmt::Debug for LogLines<W> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LogLines").field("every", &self.every).finish_non_exhaustive()
    }
}

impl<W: Write + Send> TermLike for LogLines<W> {
    fn width(&self) -> u16 {
        // Wide enough that indicatif never truncates a line for a log.
        240
    }

    fn move_cursor_up(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn move_cursor_down(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn move_cursor_right(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn move_cursor_left(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn write_line(&self, line: &str) -> io::Result<()> {
        self.write_str(line)
    }

    fn write_str(&self, line: &str) -> io::Result<()> {
        let line = line.trim_end();
        let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
        if line.is_empty() || last.elapsed() < self.every {
            return Ok(());
        }
        *last = Instant::now();
        writeln!(self.out.lock().unwrap_or_else(|p| p.into_inner()), "{line}")
    }

    fn clear_line(&self) -> io::Result<()> {
        Ok(())
    }

    fn flush(&self) -> io::Result<()> {
        self.out.lock().unwrap_or_else(|p| p.into_inner()).flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn a_log_line_drops_the_bar_and_leads_with_the_time() {
        assert_eq!(
            log_template("{bar:40} {pos}/{len} agent steps in {msg} cells, eta {eta}"),
            "[{elapsed_precise}] {pos}/{len} agent steps in {msg} cells, eta {eta}"
        );
        assert_eq!(log_template("{pos}/{len} scans"), "[{elapsed_precise}] {pos}/{len} scans");
    }

    /// A writer the test keeps a handle on after the bar owns its target.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);

    impl Write for Shared {
        fn write(&mut self, bytes: &[u8]) -> io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(bytes);
            Ok(bytes.len())
        }

        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// What a 10-step bar advanced 3 steps writes to a log that takes a line per `every`.
    fn logged(every: Duration) -> String {
        let sink = Shared::default();
        let target = ProgressDrawTarget::term_like(Box::new(LogLines::new(sink.clone(), every)));
        let bar = ProgressBar::with_draw_target(Some(10), target)
            .with_style(style(&log_template("{bar:10} {pos}/{len} steps")));
        for _ in 0..3 {
            bar.inc(1);
            bar.tick();
        }
        bar.finish_and_clear();
        String::from_utf8(sink.0.lock().unwrap().clone()).unwrap()
    }

    #[test]
    fn a_log_gets_plain_lines_at_most_once_per_period() {
        let every_draw = logged(Duration::ZERO);
        assert!(every_draw.lines().count() >= 3, "{every_draw}");
        assert!(
            every_draw.lines().all(|l| l.starts_with("[00:00:0") && l.ends_with("/10 steps")),
            "plain lines, time first, no bar: {every_draw}"
        );
        assert!(every_draw.contains("] 3/10 steps"), "{every_draw}");
        assert_eq!(logged(Duration::from_secs(3600)), "", "a run shorter than the period logs nothing");
    }
}
