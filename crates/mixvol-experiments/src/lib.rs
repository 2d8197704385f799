//! The papers' experiments and reports, built on the `mixvol` library and kept out of it:
//!
//! - [`kraus`]: Kraus & Bürger's opacity- vs extinction-based sampling experiments (CPU), the
//!   report behind `mixvol kraus` (`docs/report/kraus.*`).
//! - [`accuracy`]: the accuracy-versus-time report behind `mixvol report`
//!   (`docs/report/accuracy-vs-time.*`): one scene under every setting that trades accuracy for
//!   time, against a high-quality reference.
//! - [`chart`]: the drawing primitives both reports' charts use.
#![warn(missing_docs)]

pub mod accuracy;
pub mod chart;
pub mod kraus;
