//! The CLI's logger: library `log` records to stderr, at the level `RUST_LOG` names (`error`,
//! `warn`, `info`, `debug`, `trace`, or `target=level` directives, of which those for `mixvol`
//! targets count) or `--verbose` (info), default `warn`. Validation-layer warnings and errors
//! always reach stderr, whatever the level.
//!
//! Also [`ValidationSummary`]: the validation summary printed when a command succeeds and when
//! it fails.

use mixvol::gpu::{GpuContext, MessageLog};
use mixvol::{Error, Result};
use std::sync::Arc;

use log::{Level, LevelFilter, Log, Metadata, Record};

/// The module whose records carry the validation layers' messages.
const VALIDATION_TARGET: &str = "mixvol::gpu::validation";

struct StderrLogger {
    level: LevelFilter,
}

impl StderrLogger {
    fn passes(&self, metadata: &Metadata<'_>) -> bool {
        metadata.level() <= self.level
            || (metadata.target().starts_with(VALIDATION_TARGET) && metadata.level() <= Level::Warn)
    }
}

impl Log for StderrLogger {
    fn enabled(&self, metadata: &Metadata<'_>) -> bool {
        self.passes(metadata)
    }

    fn log(&self, record: &Record<'_>) {
        if self.passes(record.metadata()) {
            eprintln!("[{} {}] {}", record.level(), record.target(), record.args());
        }
    }

    fn flush(&self) {}
}

/// The level a `RUST_LOG` value names for mixvol's records (`None`: it names none).
fn level_of(spec: &str) -> Option<LevelFilter> {
    spec.split(',')
        .filter_map(|directive| {
            let directive = directive.trim();
            match directive.split_once('=') {
                Some((target, level)) if target.starts_with("mixvol") => level.parse().ok(),
                Some(_) => None,
                None => directive.parse().ok(),
            }
        })
        .max()
}

/// Installs the logger (see the module docs).
pub fn install(verbose: bool) {
    let from_env = std::env::var("RUST_LOG").ok().and_then(|s| level_of(&s));
    let mut level = from_env.unwrap_or(LevelFilter::Warn);
    if verbose {
        level = level.max(LevelFilter::Info);
    }
    static LOGGER: std::sync::OnceLock<StderrLogger> = std::sync::OnceLock::new();
    if log::set_logger(LOGGER.get_or_init(|| StderrLogger { level })).is_ok() {
        // Warnings are let through for the validation target even below `warn`.
        log::set_max_level(level.max(LevelFilter::Warn));
    }
}

/// The validation summary of a command: watch the context once it exists (declare the summary
/// before the context, so that it is dropped after it), then [`ValidationSummary::finish`] after
/// dropping the context. When the command fails before `finish`, the summary is printed on drop.
#[derive(Default)]
pub struct ValidationSummary {
    log: Option<Arc<MessageLog>>,
}

impl ValidationSummary {
    /// Watches `ctx`'s message log when validation is on.
    pub fn watch(&mut self, ctx: &GpuContext) {
        if ctx.info().validation {
            self.log = Some(ctx.message_log());
        }
    }

    /// Prints the summary (the count on stdout, each warning or error on stderr); fails when
    /// there was any. Call after the context is dropped (its shutdown reports leaks).
    pub fn finish(mut self) -> Result<()> {
        let Some(log) = self.log.take() else {
            return Ok(());
        };
        let problems = log.warnings_and_errors();
        println!("validation: {} warnings/errors", problems.len());
        for m in &problems {
            eprintln!("  {:?} {}: {}", m.severity, m.id_name, m.text);
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(Error::InvalidInput(format!(
                "validation reported {} problem(s)",
                problems.len()
            )))
        }
    }
}

impl Drop for ValidationSummary {
    fn drop(&mut self) {
        // Only on the failure path: `finish` took the log.
        if let Some(log) = self.log.take() {
            let problems = log.warnings_and_errors();
            eprintln!(
                "validation (the command failed): {} warnings/errors",
                problems.len()
            );
            for m in &problems {
                eprintln!("  {:?} {}: {}", m.severity, m.id_name, m.text);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{level_of, StderrLogger, VALIDATION_TARGET};
    use log::{Level, LevelFilter, Metadata};

    #[test]
    fn validation_warnings_pass_at_any_level() {
        let quiet = StderrLogger {
            level: LevelFilter::Error,
        };
        let at = |target, level| Metadata::builder().target(target).level(level).build();
        assert!(quiet.passes(&at(VALIDATION_TARGET, Level::Warn)));
        assert!(!quiet.passes(&at(VALIDATION_TARGET, Level::Info)));
        assert!(!quiet.passes(&at("mixvol::store", Level::Warn)));
        assert!(quiet.passes(&at("mixvol::store", Level::Error)));
    }

    #[test]
    fn rust_log_directives_for_mixvol_set_the_level() {
        assert_eq!(level_of("debug"), Some(LevelFilter::Debug));
        assert_eq!(level_of("wgpu=trace,mixvol=info"), Some(LevelFilter::Info));
        assert_eq!(level_of("other=trace"), None);
        assert_eq!(level_of("nonsense"), None);
    }
}
