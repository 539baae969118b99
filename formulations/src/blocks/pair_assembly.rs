//! One contact between two bodies in a step problem (`docs/model.md#contact-between-two-bodies`):
//! its unknowns, its data blocks and its residual blocks, added to a [`Problem`] in one call,
//! and the values of its unknowns in a solution vector.
//!
//! A body enters as its velocity `ν` and end-of-step pose `q`, each an [`Input`]: a variable
//! block for a dynamic body (whose Newton–Euler rows the contact's impulse is added to) or a
//! data block for a fixed or kinematic one (which gets no impulse). The blocks are the same
//! either way.

use nalgebra::Vector3;

use ecp_model::{BlockMcp, DataBlock, DataId, Input, ModelError, Problem, VarBlock, VarId};

use super::FRICTION_DATA;
use super::contact::HullFaces;
use super::friction::{FrictionEllipsoid, FrictionParams};
use super::pair_contact::{PairAlignment, PairNormalCone, PairNormalisation, PairSeparation};
use super::pair_friction::PairFriction;
use super::pair_wrench::{PairSide, PairWrench};
use crate::geometry::ConvexHull;

/// Components of a pair contact's reference-axis data block (`<tag>.axis`).
pub const AXIS_DATA: [&str; 3] = ["x", "y", "z"];

/// The faces of a convex body in its body frame, `f_i(p) = n̂_iᵀ p − d_i ≤ 0`: a hull's merged
/// faces, or the single face of a half-space (the one-face body that reduces a pair contact to
/// the half-space rows C1–C5, `docs/model.md#contact-between-two-bodies`).
#[derive(Clone, Debug, PartialEq)]
pub struct FaceSet {
    /// Outward unit normals `n̂_i`.
    pub normals: Vec<Vector3<f64>>,
    /// Offsets `d_i`.
    pub offsets: Vec<f64>,
}

impl FaceSet {
    /// The faces of a convex hull.
    pub fn of_hull(hull: &ConvexHull) -> Self {
        FaceSet {
            normals: hull.faces().iter().map(|f| f.normal).collect(),
            offsets: hull.faces().iter().map(|f| f.offset).collect(),
        }
    }

    /// One face `n̂·p ≤ d` (body frame; `normal` of any non-zero length is normalised, and the
    /// offset with it). `None` for a zero or non-finite normal.
    pub fn half_space(normal: &Vector3<f64>, offset: f64) -> Option<Self> {
        let len = normal.norm();
        (len > 0.0 && len.is_finite() && offset.is_finite()).then(|| FaceSet {
            normals: vec![normal / len],
            offsets: vec![offset / len],
        })
    }

    /// Number of faces.
    pub fn len(&self) -> usize {
        self.normals.len()
    }

    /// True when there is no face.
    pub fn is_empty(&self) -> bool {
        self.normals.is_empty()
    }
}

/// One body of a pair contact, as the step problem sees it.
#[derive(Clone, Copy, Debug)]
pub struct PairBody<'a> {
    /// Its velocity `ν = (v, ω)` (6): a variable block for a dynamic body (the contact adds its
    /// impulse to the rows paired with it, [`PairWrench`]), a data block for a fixed (zeros) or
    /// kinematic (the prescribed velocity over the step) one.
    pub nu: Input,
    /// Its end-of-step pose `q = (x, Q)` (7): variable or data, as `nu`.
    pub q: Input,
    /// Its faces, body frame (the rows `f_i` of F, `g_j` of G).
    pub faces: &'a FaceSet,
}

impl PairBody<'_> {
    /// The variable block of a dynamic body's `ν` (`None` for a fixed or kinematic body).
    pub fn dynamic(&self) -> Option<VarId> {
        match self.nu {
            Input::Var(v) => Some(v),
            Input::Data(_) => None,
        }
    }
}

/// The data blocks of one pair contact.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairDataIds {
    /// Friction parameters of the pair (4, [`FRICTION_DATA`]: μ, e_t, e_o, e_r).
    pub friction: DataId,
    /// Reference axis of the contact frame (3, [`AXIS_DATA`]; [`super::reference_axis`]),
    /// chosen per step.
    pub axis: DataId,
}

/// Declares the data blocks `<tag>.friction` and `<tag>.axis` of a pair contact.
pub fn add_pair_data(
    problem: &mut Problem,
    tag: &str,
    friction: &FrictionParams,
    axis: &Vector3<f64>,
) -> PairDataIds {
    PairDataIds {
        friction: problem.add_data_block(
            DataBlock::new(format!("{tag}.friction"), friction.values())
                .with_component_names(FRICTION_DATA),
        ),
        axis: problem.add_data_block(
            DataBlock::new(format!("{tag}.axis"), axis.as_slice()).with_component_names(AXIS_DATA),
        ),
    }
}

/// The unknowns of one pair contact (`docs/model.md#contact-between-two-bodies`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairContactVars {
    /// ECP on Conv(F) (3, free, K1).
    pub a1: VarId,
    /// ECP on Conv(G) (3, free, K2).
    pub a2: VarId,
    /// Multipliers of F's faces (m_F, ≥ 0).
    pub l: VarId,
    /// Multipliers of G's faces (m_G, ≥ 0).
    pub mu: VarId,
    /// Separation d (1, free, K3).
    pub d: VarId,
    /// Normal impulse (1, ≥ 0, K4).
    pub pn: VarId,
    /// Friction impulses `(p_t, p_o, p_r)` (3, free).
    pub pf: VarId,
    /// Slip rate σ (1, ≥ 0).
    pub sigma: VarId,
}

/// Values of one pair contact's unknowns: a starting guess to write into `z`, or what a
/// solution holds.
#[derive(Clone, Debug, PartialEq)]
pub struct PairContactValues {
    /// ECP on Conv(F).
    pub a1: Vector3<f64>,
    /// ECP on Conv(G).
    pub a2: Vector3<f64>,
    /// Multipliers of F's faces.
    pub l: Vec<f64>,
    /// Multipliers of G's faces.
    pub mu: Vec<f64>,
    /// Separation.
    pub d: f64,
    /// Normal impulse.
    pub pn: f64,
    /// Friction impulses `(p_t, p_o, p_r)`.
    pub pf: [f64; 3],
    /// Slip rate.
    pub sigma: f64,
}

impl PairContactVars {
    /// Writes `values` into `z` (the layout of `mcp`). Errors when a multiplier vector has the
    /// wrong length.
    pub fn write(
        &self,
        mcp: &BlockMcp,
        z: &mut [f64],
        values: &PairContactValues,
    ) -> Result<(), ModelError> {
        let blocks: [(VarId, &[f64]); 8] = [
            (self.a1, values.a1.as_slice()),
            (self.a2, values.a2.as_slice()),
            (self.l, &values.l),
            (self.mu, &values.mu),
            (self.d, std::slice::from_ref(&values.d)),
            (self.pn, std::slice::from_ref(&values.pn)),
            (self.pf, &values.pf),
            (self.sigma, std::slice::from_ref(&values.sigma)),
        ];
        for (v, vals) in blocks {
            let range = mcp.range(v);
            if range.len() != vals.len() || range.end > z.len() {
                return Err(ModelError::InvalidBlock {
                    block: mcp.variable_blocks()[v.0].name().to_string(),
                    reason: format!(
                        "{} values given for a block of size {} (z of length {})",
                        vals.len(),
                        range.len(),
                        z.len()
                    ),
                });
            }
            z[range].copy_from_slice(vals);
        }
        Ok(())
    }

    /// The values in `z` (the layout of `mcp`).
    pub fn read(&self, mcp: &BlockMcp, z: &[f64]) -> PairContactValues {
        let get = |v: VarId| &z[mcp.range(v)];
        let v3 = |v: VarId| Vector3::from_column_slice(get(v));
        let pf = get(self.pf);
        PairContactValues {
            a1: v3(self.a1),
            a2: v3(self.a2),
            l: get(self.l).to_vec(),
            mu: get(self.mu).to_vec(),
            d: get(self.d)[0],
            pn: get(self.pn)[0],
            pf: [pf[0], pf[1], pf[2]],
            sigma: get(self.sigma)[0],
        }
    }
}

/// Adds one contact between F and G to `problem`: the unknowns `<tag>.a1`, `.a2`, `.l`, `.mu`,
/// `.d`, `.pn`, `.pf`, `.sigma`; the rows (K1)–(K4), the face rows of F and G, the friction rows
/// on the relative velocity and the cone row (`docs/model.md#contact-between-two-bodies`); and
/// the contact impulse as a term on the Newton–Euler rows of each dynamic body (`+W(F, a1) p`
/// on F, `−W(G, a2) p` on G; a body whose `ν` is data gets none).
///
/// `scale` is the row scale of the length-valued rows, `1/h` as for the half-space rows
/// (`docs/model.md#contact`); `data` the pair's friction and reference-axis data
/// ([`add_pair_data`]). The caller pairs each dynamic body's `ν` with its
/// [`super::NewtonEuler`] block and its `q` with its [`super::KinematicMap`].
pub fn add_pair_contact(
    problem: &mut Problem,
    tag: &str,
    f: &PairBody<'_>,
    g: &PairBody<'_>,
    data: PairDataIds,
    scale: f64,
) -> Result<PairContactVars, ModelError> {
    let (m_f, m_g) = (f.faces.len(), g.faces.len());
    if m_f == 0 || m_g == 0 {
        return Err(ModelError::InvalidBlock {
            block: tag.to_string(),
            reason: "a body of a pair contact has no face; give each body its hull's faces \
                     (FaceSet::of_hull) or a half-space's face (FaceSet::half_space)"
                .into(),
        });
    }
    let point = |p: &mut Problem, name: &str| {
        p.add_variable_block(
            VarBlock::free(format!("{tag}.{name}"), 3).with_component_names(["x", "y", "z"]),
        )
    };
    let a1 = point(problem, "a1");
    let a2 = point(problem, "a2");
    let vars = PairContactVars {
        a1,
        a2,
        l: problem.add_variable_block(VarBlock::nonnegative(format!("{tag}.l"), m_f)),
        mu: problem.add_variable_block(VarBlock::nonnegative(format!("{tag}.mu"), m_g)),
        d: problem.add_variable_block(VarBlock::free(format!("{tag}.d"), 1)),
        pn: problem.add_variable_block(VarBlock::nonnegative(format!("{tag}.pn"), 1)),
        pf: problem.add_variable_block(
            VarBlock::free(format!("{tag}.pf"), 3).with_component_names(["pt", "po", "pr"]),
        ),
        sigma: problem.add_variable_block(VarBlock::nonnegative(format!("{tag}.sigma"), 1)),
    };
    let (n_f, n_g) = (f.faces.normals.clone(), g.faces.normals.clone());
    let v = |id: VarId| Input::Var(id);
    let PairContactVars {
        a1,
        a2,
        l,
        mu,
        d,
        pn,
        pf,
        sigma,
    } = vars;
    problem.add_residual_block(
        a1,
        PairAlignment::new(n_g.clone(), scale),
        &[v(a1), v(a2), v(d), v(mu), g.q],
    )?;
    problem.add_residual_block(
        a2,
        PairNormalCone::new(n_f.clone(), n_g.clone()),
        &[v(mu), g.q, v(l), f.q],
    )?;
    problem.add_residual_block(d, PairNormalisation::new(m_g), &[v(mu)])?;
    problem.add_residual_block(
        l,
        HullFaces {
            face_normals: n_f,
            offsets: f.faces.offsets.clone(),
            scale,
        },
        &[v(a1), f.q],
    )?;
    problem.add_residual_block(
        mu,
        HullFaces {
            face_normals: n_g.clone(),
            offsets: g.faces.offsets.clone(),
            scale,
        },
        &[v(a2), g.q],
    )?;
    problem.add_residual_block(pn, PairSeparation { scale }, &[v(d)])?;
    let (fric, axis) = (Input::Data(data.friction), Input::Data(data.axis));
    problem.add_residual_block(
        pf,
        PairFriction::new(n_g.clone()),
        &[
            f.nu,
            f.q,
            g.nu,
            g.q,
            v(a1),
            v(a2),
            v(mu),
            v(pn),
            v(pf),
            v(sigma),
            fric,
            axis,
        ],
    )?;
    problem.add_residual_block(sigma, FrictionEllipsoid, &[v(pn), v(pf), fric])?;
    if let Some(nu_f) = f.dynamic() {
        problem.add_term(
            nu_f,
            PairWrench::new(PairSide::F, n_g.clone()),
            &[v(a1), f.q, v(mu), g.q, v(pn), v(pf), axis],
        )?;
    }
    if let Some(nu_g) = g.dynamic() {
        problem.add_term(
            nu_g,
            PairWrench::new(PairSide::G, n_g),
            &[v(a2), v(mu), g.q, v(pn), v(pf), axis],
        )?;
    }
    Ok(vars)
}
