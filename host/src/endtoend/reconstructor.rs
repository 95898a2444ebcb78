//! The tomographic reconstructor and the DM projection.
//!
//! ## Layer model
//! Each turbulent layer's optical path difference is modelled as a bilinear
//! interpolation of values on a square lattice of nodes of half the lenslet
//! pitch `d` ([`NODES_PER_SUBAPERTURE`]), aligned so that the ground
//! layer's nodes include the sub-apertures' corners (Fried geometry), and
//! covering every point any wavefront sensor or the science path sees at
//! that altitude. Nodes that no measurement and no science point touches
//! are left out. The finer lattice matters: on the noiseless single ground
//! layer of the CANARY pupil, with unaliased slopes, the residual was 165
//! nm with nodes at pitch `d` and 152 nm at `d/2`, against a 133 nm fitting
//! error (the rest is what the DM could fit but the lenslets do not see:
//! the unlit edge and obscuration, frequencies near the cut-off); the
//! matrices stay small (a few hundred nodes per layer).
//!
//! ## Measurement model
//! A sub-aperture's slope is the G-tilt (the average gradient over its lit
//! part: what a centre of gravity of an untruncated spot measures) of the
//! sum of the layers seen in its star's direction, in pixels: `s = G x`,
//! with `x` the node values (m). `G` is computed exactly for the bilinear
//! model by averaging its analytic gradient over 16 x 16 points per
//! sub-aperture (those inside the pupil annulus).
//!
//! ## Regularised least squares
//! `x^ = argmin |s - G x|^2 / sigma^2 + x^T C^-1 x = C G^T (G C G^T +
//! sigma^2 I)^-1 s`: least squares on the layer phases, regularised by the
//! layers' von Kármán covariance `C` (each layer its share of the
//! turbulence, the true outer scale, capped at 1 km for the prior when
//! infinite; nodes of different layers uncorrelated) and white slope noise
//! of variance `sigma^2` (px^2). With `sigma^2` the slopes' true noise this
//! is the minimum-mean-square-error (MAP) estimate of the layered model;
//! the second form needs no inverse of the (ill-conditioned) `C`.
//!
//! ## Projection onto the DM
//! The on-axis phase estimate `P x^` (the layers summed in the science
//! direction, on the science grid) is fitted by the DM in least squares
//! over the pupil, piston excluded: `c = (H~^T H~ + eps I)^-1 H~^T P x^`,
//! `H~` the influence functions with their pupil mean removed, `eps` =
//! 1e-6 of the mean diagonal (the sum of all influence functions is nearly
//! piston). The whole chain is one matrix `M = F P C G^T (G C G^T +
//! sigma^2 I)^-1` from slopes to DM commands.

use anyhow::{anyhow, Result};
use nalgebra::{Cholesky, DMatrix};
use std::collections::HashMap;

use super::covariance::phase_covariance;
use super::geometry::{DeformableMirror, Lenslets, Pupil, ScienceGrid};
use crate::simulator::ARCSEC_PER_RAD;

/// What the reconstructor is built from.
pub struct ModelGeometry<'a> {
    pub pupil: &'a Pupil,
    pub lenslets: &'a Lenslets,
    /// Each wavefront sensor's direction, `[x, y]` radians.
    pub wfs_directions: &'a [[f64; 2]],
    pub science_direction: [f64; 2],
    /// `(altitude m, fraction)` of each layer.
    pub layers: &'a [(f64, f64)],
    /// Fried parameter (m) at `r0_wavelength_m`, outer scale (m).
    pub r0_m: f64,
    pub r0_wavelength_m: f64,
    pub outer_scale_m: f64,
    pub pixel_scale_arcsec: f64,
    pub dm: &'a DeformableMirror,
    pub science: &'a ScienceGrid,
    /// Layer nodes per sub-aperture pitch, each axis
    /// ([`NODES_PER_SUBAPERTURE`] for the MMSE reconstructor).
    pub nodes_per_subaperture: usize,
}

/// One layer's node lattice.
struct Lattice {
    altitude_m: f64,
    /// Lattice index of node `(0, 0)` of the local grid.
    m0: [i64; 2],
    size: [usize; 2],
}

impl Lattice {
    fn index(&self, i: i64, j: i64) -> usize {
        let (a, b) = ((i - self.m0[0]) as usize, (j - self.m0[1]) as usize);
        debug_assert!(a < self.size[0] && b < self.size[1]);
        b * self.size[0] + a
    }
}

/// Bilinear weights of point `u` (m) on a lattice of pitch `p` whose node
/// `m` is at `(m - half) p`: the cell's lower node `(i, j)` and `(fx, fy)`.
fn cell(u: [f64; 2], p: f64, half: f64) -> ([i64; 2], [f64; 2]) {
    let a = [u[0] / p + half, u[1] / p + half];
    let i = [a[0].floor(), a[1].floor()];
    ([i[0] as i64, i[1] as i64], [a[0] - i[0], a[1] - i[1]])
}

/// Layer nodes per sub-aperture pitch (each axis) of the MMSE
/// reconstructor.
pub const NODES_PER_SUBAPERTURE: usize = 2;

/// The reconstructor's fixed part: everything but the noise level.
pub struct Tomography {
    /// Slopes x nodes (px per metre).
    pub g: DMatrix<f64>,
    /// `G C G^T` (px^2).
    gcgt: DMatrix<f64>,
    /// `F P C G^T`: actuators x slopes.
    b: DMatrix<f64>,
    /// `F P`: actuators x nodes, the DM's fit of the layers' on-axis sum
    /// (what the plain least-squares reconstructor needs without `C`).
    pub(super) fp: DMatrix<f64>,
    pub nodes: usize,
}

/// The science path: the DM's influence on the science grid and the fit.
pub struct Science {
    /// Points x actuators, each column's pupil mean removed (`H~`).
    pub h: DMatrix<f64>,
    /// `H~^T W H~` with `W = I / points` (the pupil average).
    pub q: DMatrix<f64>,
    /// `(Q + eps I)^-1 H~^T W`: actuators x points, the DM's best fit.
    pub fit: DMatrix<f64>,
}

impl Science {
    pub fn new(dm: &DeformableMirror, grid: &ScienceGrid) -> Science {
        let (np, na) = (grid.points.len(), dm.actuators.len());
        let mut h = DMatrix::from_fn(np, na, |p, a| dm.influence(a, grid.points[p]));
        for mut col in h.column_iter_mut() {
            let mean = col.mean();
            col.add_scalar_mut(-mean);
        }
        let w = 1.0 / np as f64;
        let q = h.tr_mul(&h) * w;
        let eps = 1e-6 * q.trace() / na as f64;
        let mut qe = q.clone();
        for k in 0..na {
            qe[(k, k)] += eps;
        }
        let fit = Cholesky::new(qe)
            .expect("H~^T H~ + eps I is positive definite")
            .solve(&(h.transpose() * w));
        Science { h, q, fit }
    }
}

impl Tomography {
    pub fn new(m: &ModelGeometry<'_>, science: &Science) -> Result<Tomography> {
        let d_sub = m.lenslets.pitch_m;
        if m.nodes_per_subaperture == 0 {
            return Err(anyhow!("at least one layer node per sub-aperture pitch"));
        }
        let p = d_sub / m.nodes_per_subaperture as f64;
        let half = (m.lenslets.across * m.nodes_per_subaperture) as f64 / 2.0;
        let n_sub = m.lenslets.subapertures.len();
        let n_s = 2 * n_sub * m.wfs_directions.len();
        let px_per_rad = ARCSEC_PER_RAD / m.pixel_scale_arcsec;

        // Every point seen, per layer: the sub-aperture samples and the
        // science points.
        const S: usize = 16;
        let sub_points: Vec<Vec<[f64; 2]>> = m
            .lenslets
            .subapertures
            .iter()
            .map(|s| {
                let mut v = Vec::with_capacity(S * S);
                for j in 0..S {
                    for i in 0..S {
                        let x = s.centre_m[0] + d_sub * ((i as f64 + 0.5) / S as f64 - 0.5);
                        let y = s.centre_m[1] + d_sub * ((j as f64 + 0.5) / S as f64 - 0.5);
                        if m.pupil.contains(x, y) {
                            v.push([x, y]);
                        }
                    }
                }
                v
            })
            .collect();
        if let Some(k) = sub_points.iter().position(|v| v.is_empty()) {
            return Err(anyhow!("sub-aperture {k} has no lit sample"));
        }
        let lattices: Vec<Lattice> = m
            .layers
            .iter()
            .map(|&(h, _)| {
                let mut lo = [i64::MAX; 2];
                let mut hi = [i64::MIN; 2];
                let mut see = |u: [f64; 2]| {
                    let (i, _) = cell(u, p, half);
                    for a in 0..2 {
                        lo[a] = lo[a].min(i[a]);
                        hi[a] = hi[a].max(i[a] + 1);
                    }
                };
                for d in m.wfs_directions {
                    for pts in &sub_points {
                        for q in pts {
                            see([q[0] + h * d[0], q[1] + h * d[1]]);
                        }
                    }
                }
                let d = m.science_direction;
                for q in &m.science.points {
                    see([q[0] + h * d[0], q[1] + h * d[1]]);
                }
                Lattice {
                    altitude_m: h,
                    m0: lo,
                    size: [(hi[0] - lo[0] + 1) as usize, (hi[1] - lo[1] + 1) as usize],
                }
            })
            .collect();
        let offsets: Vec<usize> = lattices
            .iter()
            .scan(0, |acc, l| {
                let o = *acc;
                *acc += l.size[0] * l.size[1];
                Some(o)
            })
            .collect();
        let full_nodes: usize = lattices.iter().map(|l| l.size[0] * l.size[1]).sum();

        // G on the full lattices.
        let mut g = DMatrix::<f64>::zeros(n_s, full_nodes);
        for (w, d) in m.wfs_directions.iter().enumerate() {
            for (k, pts) in sub_points.iter().enumerate() {
                let row = (w * n_sub + k) * 2;
                let scale = px_per_rad / (pts.len() as f64 * p);
                for (l, lat) in lattices.iter().enumerate() {
                    let h = lat.altitude_m;
                    for q in pts {
                        let (i, f) = cell([q[0] + h * d[0], q[1] + h * d[1]], p, half);
                        let n00 = offsets[l] + lat.index(i[0], i[1]);
                        let n10 = offsets[l] + lat.index(i[0] + 1, i[1]);
                        let n01 = offsets[l] + lat.index(i[0], i[1] + 1);
                        let n11 = offsets[l] + lat.index(i[0] + 1, i[1] + 1);
                        let (fx, fy) = (f[0], f[1]);
                        g[(row, n00)] -= (1.0 - fy) * scale;
                        g[(row, n10)] += (1.0 - fy) * scale;
                        g[(row, n01)] -= fy * scale;
                        g[(row, n11)] += fy * scale;
                        g[(row + 1, n00)] -= (1.0 - fx) * scale;
                        g[(row + 1, n10)] -= fx * scale;
                        g[(row + 1, n01)] += (1.0 - fx) * scale;
                        g[(row + 1, n11)] += fx * scale;
                    }
                }
            }
        }
        // P: the layers summed in the science direction, on the science grid.
        let np = m.science.points.len();
        let mut proj = DMatrix::<f64>::zeros(np, full_nodes);
        let d = m.science_direction;
        for (r, q) in m.science.points.iter().enumerate() {
            for (l, lat) in lattices.iter().enumerate() {
                let h = lat.altitude_m;
                let (i, f) = cell([q[0] + h * d[0], q[1] + h * d[1]], p, half);
                let (fx, fy) = (f[0], f[1]);
                proj[(r, offsets[l] + lat.index(i[0], i[1]))] += (1.0 - fx) * (1.0 - fy);
                proj[(r, offsets[l] + lat.index(i[0] + 1, i[1]))] += fx * (1.0 - fy);
                proj[(r, offsets[l] + lat.index(i[0], i[1] + 1))] += (1.0 - fx) * fy;
                proj[(r, offsets[l] + lat.index(i[0] + 1, i[1] + 1))] += fx * fy;
            }
        }
        // Keep the nodes something touches.
        let used: Vec<usize> = (0..full_nodes)
            .filter(|&n| {
                g.column(n).iter().any(|&v| v != 0.0) || proj.column(n).iter().any(|&v| v != 0.0)
            })
            .collect();
        let g = g.select_columns(&used);
        let proj = proj.select_columns(&used);
        // Node positions and layers, for the prior.
        let mut node_layer = Vec::with_capacity(used.len());
        for &n in &used {
            let l = offsets.iter().rposition(|&o| o <= n).expect("offset 0");
            let lat = &lattices[l];
            let local = n - offsets[l];
            let (a, b) = (local % lat.size[0], local / lat.size[0]);
            node_layer.push((l, lat.m0[0] + a as i64, lat.m0[1] + b as i64));
        }
        let l0 = if m.outer_scale_m.is_finite() {
            m.outer_scale_m
        } else {
            1000.0
        };
        let to_m2 = (m.r0_wavelength_m / (2.0 * std::f64::consts::PI)).powi(2);
        let mut cache: HashMap<i64, f64> = HashMap::new();
        let nn = used.len();
        let mut c = DMatrix::<f64>::zeros(nn, nn);
        for a in 0..nn {
            for b in a..nn {
                let (la, ia, ja) = node_layer[a];
                let (lb, ib, jb) = node_layer[b];
                if la != lb {
                    continue;
                }
                let r2 = (ia - ib).pow(2) + (ja - jb).pow(2);
                let base = *cache.entry(r2).or_insert_with(|| {
                    phase_covariance((r2 as f64).sqrt() * p, m.r0_m, l0) * to_m2
                });
                let v = base * m.layers[la].1;
                c[(a, b)] = v;
                c[(b, a)] = v;
            }
        }
        let cgt = &c * g.transpose();
        let gcgt = &g * &cgt;
        let fp = &science.fit * proj;
        let b = &fp * cgt;
        Ok(Tomography {
            g,
            gcgt,
            b,
            fp,
            nodes: nn,
        })
    }

    /// Slopes.
    pub fn slopes(&self) -> usize {
        self.gcgt.nrows()
    }

    /// `M(sigma^2)`: DM commands (m) from slopes (px), for white slope
    /// noise of variance `sigma2_px2`.
    pub fn reconstructor(&self, sigma2_px2: f64) -> DMatrix<f64> {
        self.reconstructor_weighted(&vec![sigma2_px2; self.slopes()])
    }

    /// `M` for independent slope noise of variance `sigma2_px2[i]` on
    /// slope `i`: `F P C G^T (G C G^T + diag(sigma^2))^-1`. Partly lit
    /// sub-apertures get fewer photons and are noisier; weighting them by
    /// their own variance is the MMSE estimate for such noise.
    pub fn reconstructor_weighted(&self, sigma2_px2: &[f64]) -> DMatrix<f64> {
        assert_eq!(sigma2_px2.len(), self.slopes(), "one variance per slope");
        let mut a = self.gcgt.clone();
        // A floor keeps the system positive definite when sigma is 0.
        let floor = 1e-9 * a.trace() / a.nrows() as f64;
        for (k, &s2) in sigma2_px2.iter().enumerate() {
            a[(k, k)] += s2.max(floor);
        }
        let chol = Cholesky::new(a).expect("G C G^T + sigma^2 I is positive definite");
        chol.solve(&self.b.transpose()).transpose()
    }
}
