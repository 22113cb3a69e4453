//! Fitting the elastic model through a sequence of target shapes (SPEC 5; the paper's
//! section 4). Per iteration: the rotations, the anisotropic surface-distance term with
//! confidence weights and invalidated associations ([`surface`]), the self-intersection
//! term ([`contact`]), and one sparse solve of
//! $(\alpha S + \beta W + \gamma I)\,x = \alpha f + \beta W t + \gamma I x'$
//! (block-Jacobi PCG warm-started from the current positions, [`crate::solve`]).
//!
//! Scales: $\beta = 1$ per surface node; $\alpha = $ `stiffness` $/ (\mu \bar h)$ with
//! $\bar h$ the mean node spacing, so that `stiffness = 1` makes a node's elastic diagonal
//! about as strong as a fully confident data term, whatever the units and material;
//! $\gamma = $ `contact` (SPEC 5: $\gamma = \beta$).

//!
//! The steps, one file each: `associate` (surface, normals, associations, invalidation),
//! [`contact`] (self-intersection), `stop` (SPEC 5 step 5), `assemble` (the system of the
//! terms), `solve` (PCG, assembled or matrix-free); `workspace` keeps what lasts across
//! frames, [`surface`] holds the surface geometry and the data term.

mod assemble;
mod associate;
pub mod contact;
pub mod coverage;
pub mod silhouette;
mod solve;
mod stop;
pub mod surface;
pub mod tracks;
pub mod volume;
mod workspace;

use crate::elastic::ElasticModel;
use crate::error::{Error, Result};
use crate::grid_sample::Field;
use assemble::assemble;
use associate::associate_surface;
use contact::{contact_terms, find_contacts, Contact};
use coverage::{coverage_term, TargetSamples};
use silhouette::{silhouette, SilhouetteView};
use stop::StopRule;
use tracks::FrameTracks;
use volume::volume_term;
pub use workspace::FitWorkspace;

/// The knobs of the per-frame iteration.
#[derive(Debug, Clone, Copy)]
pub struct FitOptions {
    /// $\alpha / \beta$ in units of $\mu \bar h$ (see the module docs).
    pub stiffness: f64,
    /// $\gamma / \beta$.
    pub contact: f64,
    /// Iteration cap per frame (SPEC 5: 10).
    pub max_iterations: usize,
    /// Stop when the last decrease of $D$ is below this fraction of the total decrease so
    /// far (SPEC 5: 1%).
    pub stop_fraction: f64,
    /// Drop colliding associations of distant parts.
    pub invalidate: bool,
    /// Push penetrating surface nodes out of other parts.
    pub self_intersection: bool,
    /// Relative residual of each linear solve.
    pub solver_tolerance: f64,
    /// Cap on PCG iterations per solve.
    pub solver_max_iterations: usize,
    /// PCG on the matrix-free product of the model instead of the assembled matrix.
    pub matrix_free: bool,
    /// Keep a node that was pushed out of another part in contact for the rest of the frame
    /// while it stays within its partner's support ([`contact::hold_contacts`]): stops the
    /// set of contacts alternating between iterations, so limbs pressed together end with
    /// far fewer penetrating nodes (two squeezed blocks: 57 -> 20), but limbs that slide
    /// past each other are held back (horse gallop at 2,500 nodes: mean drift 2.1% ->
    /// 2.7%; benches/README.md). Off by default.
    pub hold_contacts: bool,
    /// Precondition the assembled system with block Jacobi plus the rigid modes of node
    /// aggregates ([`TwoLevel`]) instead of block Jacobi alone.
    pub coarse: bool,
    /// Weight of the coverage term relative to the surface term ([`coverage`], SPEC 5.1);
    /// 0 turns it off. Acts only when the frame's [`FrameTargets`] carry samples.
    pub coverage: f64,
    /// Weight of the volume term ([`volume`]): a volume error of $\delta$ times the rest
    /// surface's area costs as much as moving every surface node by $\delta$ under a data
    /// term of this weight; 0 turns it off.
    pub volume: f64,
    /// Weight of the silhouette term per surface node and camera ([`silhouette`]); 0 turns
    /// it off. Acts only when the frame's [`FrameTargets`] carry silhouettes.
    pub silhouette: f64,
}

/// What a frame is fitted to besides its signed distance field: the data of SPEC 5.1's
/// terms, each optional.
#[derive(Debug, Clone, Copy, Default)]
pub struct FrameTargets<'a, const D: usize> {
    /// Samples of the target surface, for the coverage term.
    pub samples: Option<&'a TargetSamples<D>>,
    /// The cameras and their masks' signed distances, for the silhouette term (3-D only).
    pub silhouettes: Option<&'a [SilhouetteView<'a>]>,
    /// Tracked points attached to the model, for the track term ([`tracks`]).
    pub tracks: Option<&'a FrameTracks<D>>,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            stiffness: 1.0,
            contact: 1.0,
            max_iterations: 10,
            stop_fraction: 0.01,
            invalidate: true,
            self_intersection: true,
            solver_tolerance: 1e-6,
            solver_max_iterations: 500,
            // Measured slower on the demo's hulls (1.87 vs 1.40 s per frame, machine loaded):
            // its two parallel passes per product cost more in synchronisation than the
            // assembled product's memory traffic at this size.
            matrix_free: false,
            coarse: true,
            hold_contacts: false,
            coverage: 2.0,
            volume: 4.0,
            silhouette: 0.0,
        }
    }
}

/// Figures of one fitted frame (SPEC 5's outputs), at the returned positions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameMetrics {
    /// $D = \sum_p w_p (x_p - t_p)^\top M_p (x_p - t_p)$.
    pub distance_term: f64,
    /// Mean $|d(x_p)|$ over surface nodes, units of the model.
    pub mean_distance: f64,
    /// Largest $|d(x_p)|$.
    pub max_distance: f64,
    /// Elastic energy.
    pub elastic_energy: f64,
    /// Surface nodes penetrating another part.
    pub penetrating: usize,
    /// Surface nodes whose association was invalidated (last iteration).
    pub invalidated: usize,
    /// Iterations run.
    pub iterations: usize,
    /// PCG iterations over all solves.
    pub solver_iterations: usize,
    /// Every linear solve reached its tolerance.
    pub solver_converged: bool,
    /// Wall-clock seconds spent assembling the system and in the linear solves.
    pub solver_seconds: f64,
    /// Target samples no model surface node explains (coverage, at the returned positions;
    /// 0 without samples).
    pub unexplained: usize,
    /// Target samples (coverage; 0 without samples).
    pub samples: usize,
    /// Wall-clock seconds per step of the iteration, in the order of [`STEPS`].
    pub step_seconds: [f64; STEPS.len()],
}

/// The steps of a frame's iteration timed in [`FrameMetrics::step_seconds`].
pub const STEPS: [&str; 10] = [
    "rotations",
    "associate",
    "contacts",
    "coverage",
    "volume",
    "energy",
    "silhouette",
    "assemble",
    "solve",
    "measure",
];

impl FitOptions {
    /// Fails unless the weights and tolerances are finite and non-negative (the stiffness
    /// positive).
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the first bad option.
    pub fn check(&self) -> Result<()> {
        for (argument, value) in [
            ("stiffness", self.stiffness),
            ("contact", self.contact),
            ("coverage", self.coverage),
            ("volume", self.volume),
            ("silhouette", self.silhouette),
            ("stop_fraction", self.stop_fraction),
            ("solver_tolerance", self.solver_tolerance),
        ] {
            if !(value.is_finite() && value >= 0.0) || (argument == "stiffness" && value <= 0.0) {
                return Err(Error::InvalidOption {
                    argument,
                    value,
                    expected: "a finite number, positive for stiffness and non-negative otherwise",
                });
            }
        }
        Ok(())
    }
}

/// Fits one frame: from `start` (the neighbouring frame's fit) towards the zero level of
/// the signed distance field `target`.
///
/// # Errors
/// Bad positions or options; [`Error::NotPositiveDefinite`] if the system loses
/// definiteness (it cannot with positive stiffness and a surface term; reported, not
/// hidden).
pub fn fit_frame<const D: usize, F: Field<D>>(
    model: &ElasticModel<D>,
    workspace: &mut FitWorkspace<D>,
    target: &F,
    start: &[[f64; D]],
    options: &FitOptions,
) -> Result<(Vec<[f64; D]>, FrameMetrics)> {
    fit_frame_with(
        model,
        workspace,
        target,
        &FrameTargets::default(),
        start,
        options,
    )
}

/// [`fit_frame`] with the data of SPEC 5.1's terms in `targets`.
///
/// # Errors
/// As [`fit_frame`].
pub fn fit_frame_with<const D: usize, F: Field<D>>(
    model: &ElasticModel<D>,
    workspace: &mut FitWorkspace<D>,
    target: &F,
    targets: &FrameTargets<'_, D>,
    start: &[[f64; D]],
    options: &FitOptions,
) -> Result<(Vec<[f64; D]>, FrameMetrics)> {
    model.check_positions(start)?;
    options.check()?;
    let (_, mu) = model.lame();
    let alpha = options.stiffness / (mu * workspace.spacing);
    let mut x = start.to_vec();
    let mut metrics = FrameMetrics {
        solver_converged: true,
        ..FrameMetrics::default()
    };
    let mut stop = StopRule::new(options.stop_fraction);
    let mut held: Vec<Contact<D>> = Vec::new();
    let mut clock = std::time::Instant::now();
    let mut lap = |metrics: &mut FrameMetrics, step: usize| {
        let now = std::time::Instant::now();
        metrics.step_seconds[step] += (now - clock).as_secs_f64();
        clock = now;
    };
    for iteration in 0..options.max_iterations {
        lap(&mut metrics, 9);
        let rotations = model.rotations(&x)?;
        lap(&mut metrics, 0);
        let surface = associate_surface(workspace, target, &x, options.invalidate);
        metrics.invalidated = surface.invalidated;
        lap(&mut metrics, 1);
        let (contacts, penetrating) =
            contact_terms(workspace, &surface, options.self_intersection, &held);
        lap(&mut metrics, 2);
        let coverage = coverage_term(
            workspace,
            &surface,
            targets.samples,
            options.coverage,
            options.invalidate,
        );
        lap(&mut metrics, 3);
        // The whole objective of the system below ($2 \alpha E + D + C$, as its normal
        // equations weigh the terms), not the data terms alone: the coverage term's pulls
        // vanish once the surface is in place, and $D + C$ then stops falling while the
        // strain they left still relaxes (a rigidly moved capsule stopped after 2
        // iterations at 11% of a 5% stretch's energy).
        let volume = volume_term(workspace, &surface.positions, x.len(), options.volume);
        lap(&mut metrics, 4);
        let elastic = 2.0 * alpha * model.energy(&x, &rotations)?;
        let penalty = volume.as_ref().map_or(0.0, |v| v.energy());
        lap(&mut metrics, 5);
        let outline = silhouette(
            targets.silhouettes.unwrap_or(&[]),
            &surface.positions,
            &surface.normals,
            &workspace.support,
            options.silhouette,
        );
        let tracked = targets.tracks.map(|t| t.term(&x)).unwrap_or_default();
        lap(&mut metrics, 6);
        if stop.should_stop(
            elastic
                + surface.distance_term()
                + coverage.energy
                + penalty
                + outline.energy
                + tracked.energy,
            penetrating,
        ) {
            break;
        }
        if options.hold_contacts {
            held.clone_from(&contacts);
        }
        metrics.iterations = iteration + 1;
        let mut system = assemble(
            model,
            workspace,
            &rotations,
            &surface,
            &contacts,
            &[&coverage.pulls[..], &outline.pulls[..]].concat(),
            alpha,
            options.contact,
        )?;
        tracked.add_to(&mut system);
        lap(&mut metrics, 7);
        let solve_clock = std::time::Instant::now();
        let status = solve::solve(
            model,
            workspace,
            &rotations,
            &system,
            alpha,
            iteration == 0,
            options,
            &mut x,
            volume.as_ref(),
        )?;
        metrics.solver_iterations += status.iterations;
        metrics.solver_converged &= status.converged;
        metrics.solver_seconds += solve_clock.elapsed().as_secs_f64();
        lap(&mut metrics, 8);
    }
    lap(&mut metrics, 9);
    measure(model, workspace, target, &x, &mut metrics)?;
    if let Some(samples) = targets.samples {
        let surface = associate_surface(workspace, target, &x, false);
        let found = coverage_term(workspace, &surface, Some(samples), 1.0, false);
        metrics.unexplained = found.unexplained;
        metrics.samples = samples.len();
    }
    lap(&mut metrics, 9);
    Ok((x, metrics))
}

/// SPEC 5's figures of a frame at its returned positions `x`, into `metrics`.
fn measure<const D: usize, F: Field<D>>(
    model: &ElasticModel<D>,
    workspace: &FitWorkspace<D>,
    target: &F,
    x: &[[f64; D]],
    metrics: &mut FrameMetrics,
) -> Result<()> {
    let surface = associate_surface(workspace, target, x, false);
    metrics.distance_term = surface.distance_term();
    let distances: Vec<f64> = surface.found.iter().map(|a| a.distance.abs()).collect();
    metrics.mean_distance = distances.iter().sum::<f64>() / distances.len() as f64;
    metrics.max_distance = distances.iter().copied().fold(0.0, f64::max);
    metrics.elastic_energy = model.energy(x, &model.rotations(x)?)?;
    // Counted whether or not the term acted, so runs with it off can be compared.
    let (positions, normals) = (&surface.positions, &surface.normals);
    metrics.penetrating = find_contacts(
        positions,
        normals,
        &workspace.rest_surface,
        &workspace.support,
    )
    .len();
    Ok(())
}

#[cfg(test)]
mod tests;
