//! The sweep of Kraus & Bürger's experiments: Figure 1 over the sampling distance, the
//! convergence table, the wall's first visible artifact, and the closed-form checks.

use super::*;

/// What [`run`] sweeps.
#[derive(Clone, Debug, PartialEq)]
pub struct KrausOptions {
    /// `tau_max` of the Figure 1 experiment.
    pub tau_max: Vec<f32>,
    /// Sampling distances `d = d0` of the Figure 1 experiment.
    pub distances: Vec<f32>,
    /// Sample phases per distance (see [`deviation`]).
    pub phases: usize,
    /// Sampling distances of the convergence table (d -> 0), for both models with `d0 = d` and
    /// the opacity model with the fixed `d0` below.
    pub convergence_distances: Vec<f32>,
    /// The fixed reference distance of the convergence table's third model.
    pub fixed_d0: f32,
    /// Extinctions of the wall.
    pub wall_tau: Vec<f32>,
    /// Deviations of the wall's opacity that count as a visible artifact.
    pub wall_thresholds: Vec<f32>,
    /// Sampling distances scanned for the wall's first visible artifact, ascending.
    pub wall_distances: Vec<f32>,
}

impl Default for KrausOptions {
    /// The paper's sweep: `tau_max = 1, 2, 4, 8`, `d = 0.1, 0.2, ..., 2.5`, 200 phases; the wall
    /// with `tau = 4, 8, 16`, thresholds 1/255, 0.01 and 0.05, scanned at `d = 0.01 .. 2.5`.
    fn default() -> Self {
        Self {
            tau_max: vec![1.0, 2.0, 4.0, 8.0],
            distances: (1..=25).map(|i| i as f32 / 10.0).collect(),
            phases: 200,
            convergence_distances: vec![0.3, 0.13, 0.07, 0.03, 0.013, 0.007, 0.003],
            fixed_d0: 1.0,
            wall_tau: vec![4.0, 8.0, 16.0],
            wall_thresholds: vec![1.0 / 255.0, 0.01, 0.05],
            wall_distances: (1..=250).map(|i| i as f32 / 100.0).collect(),
        }
    }
}

/// One experiment, model, extinction and distance of a [`KrausReport`].
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// `figure1`, `convergence` or `wall`.
    pub experiment: &'static str,
    /// The sampling model.
    pub model: Model,
    /// `tau_max` (Figure 1) or the wall's `tau`.
    pub tau: f32,
    /// Sampling distance.
    pub d: f32,
    /// Exact opacity (closed form).
    pub exact_alpha: f64,
    /// Deviations over the phases.
    pub stats: DeviationStats,
}

/// Where the wall first deviates visibly.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct WallOnset {
    /// The wall's extinction.
    pub tau: f32,
    /// The deviation that counts as visible.
    pub threshold: f32,
    /// Smallest scanned `d` at which opacity-based sampling deviates by more than `threshold`
    /// for some phase (`None`: never in the scanned range).
    pub opacity: Option<f32>,
    /// The same for extinction-based sampling.
    pub extinction: Option<f32>,
}

/// The numeric exact integral against the closed form, for one set-up.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ExactCheck {
    /// `tau_max` of the Figure 1 set-up.
    pub tau: f32,
    /// Closed-form opacity `1 - exp(-tau_max)`.
    pub closed_form: f64,
    /// The numeric result ([`exact`]), largest component difference from the closed form.
    pub numeric_difference: f64,
    /// The numeric integration's own error estimate.
    pub error_estimate: f64,
}

/// Everything [`run`] measured.
#[derive(Clone, Debug, PartialEq)]
pub struct KrausReport {
    /// What was swept.
    pub options: KrausOptions,
    /// All measured rows (Figure 1, convergence, wall).
    pub rows: Vec<Row>,
    /// Onsets of visible wall artifacts per extinction and threshold.
    pub wall_onsets: Vec<WallOnset>,
    /// Numeric exact integral against the closed form, per `tau_max`.
    pub exact_checks: Vec<ExactCheck>,
}

/// Runs the experiments. The options are checked (distances finite and > 0, at least one phase).
pub fn run(options: &KrausOptions) -> Result<KrausReport> {
    if let Some(&d) = options
        .distances
        .iter()
        .chain(&options.convergence_distances)
        .chain(&options.wall_distances)
        .find(|d| !(d.is_finite() && **d > 0.0))
    {
        return Err(Error::InvalidInput(format!(
            "sampling distance {d} must be finite and > 0"
        )));
    }
    let mut rows = Vec::new();
    let mut exact_checks = Vec::new();
    for &tau in &options.tau_max {
        let setup = figure1(tau)?;
        let numeric = exact(&setup.grid, &setup.ray)?;
        exact_checks.push(ExactCheck {
            tau,
            closed_form: setup.exact[3],
            numeric_difference: numeric
                .rgba
                .iter()
                .zip(setup.exact)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max),
            error_estimate: numeric.error_estimate,
        });
        for &d in &options.distances {
            for model in [Model::OPACITY, Model::EXTINCTION] {
                rows.push(Row {
                    experiment: "figure1",
                    model,
                    tau,
                    d,
                    exact_alpha: setup.exact[3],
                    stats: deviation(&setup, model, d, setup.exact, options.phases)?,
                });
            }
        }
        let fixed = Model::OpacityBased(ReferenceDistance::Fixed(options.fixed_d0));
        for &d in &options.convergence_distances {
            for model in [Model::OPACITY, Model::EXTINCTION, fixed] {
                rows.push(Row {
                    experiment: "convergence",
                    model,
                    tau,
                    d,
                    exact_alpha: setup.exact[3],
                    stats: deviation(&setup, model, d, setup.exact, options.phases)?,
                });
            }
        }
    }
    let mut wall_onsets = Vec::new();
    for &tau in &options.wall_tau {
        let setup = wall(tau)?;
        let first = rows.len();
        for &d in &options.wall_distances {
            for model in [Model::OPACITY, Model::EXTINCTION] {
                rows.push(Row {
                    experiment: "wall",
                    model,
                    tau,
                    d,
                    exact_alpha: setup.exact[3],
                    stats: deviation(&setup, model, d, setup.exact, options.phases)?,
                });
            }
        }
        let scanned = &rows[first..];
        for &threshold in &options.wall_thresholds {
            let onset = |model: Model| {
                scanned
                    .iter()
                    .find(|r| r.model == model && r.stats.max > threshold as f64)
                    .map(|r| r.d)
            };
            wall_onsets.push(WallOnset {
                tau,
                threshold,
                opacity: onset(Model::OPACITY),
                extinction: onset(Model::EXTINCTION),
            });
        }
    }
    Ok(KrausReport {
        options: options.clone(),
        rows,
        wall_onsets,
        exact_checks,
    })
}
