//! The structural view of a contact step (`docs/backends.md#conic`): what a structure-exploiting
//! backend needs from a time step of the contact model, without the solver crate knowing the
//! formulation's types.
//!
//! A step problem of `docs/model.md` is, besides an MCP, a set of bodies with a mass matrix
//! and a free-motion velocity, and a set of contacts between the convex hull Conv(F) of a body
//! and a fixed half-space G. A backend such as the conic one (Anitescu 2006; Acary, Cadoux,
//! Lemaréchal, Malick 2011) asks for the contact geometry at a trial end-of-step configuration
//! (taken from a full MCP vector `z`), solves its own subproblem, and hands back velocities and
//! impulses; [`StepStructure::assemble`] maps them to the full MCP vector (ν, q, a1, a2, l, l_g,
//! p, σ) so that the result is judged by the same natural residual as every other backend
//! (`docs/model.md#mcp`).
//!
//! Vectors are plain arrays in the world frame (this crate has no linear-algebra dependency).
//! The MCP of a step exposes its structure through [`crate::Mcp::structure`].

/// Friction parameters of one contact (`docs/model.md#friction`): Coulomb coefficient `μ ≥ 0` and
/// the semi-axes of the limit ellipsoid, `e_t, e_o > 0` dimensionless and `e_r > 0` a length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactFriction {
    /// Friction coefficient μ.
    pub mu: f64,
    /// Semi-axis along the first tangent t.
    pub e_t: f64,
    /// Semi-axis along the second tangent o.
    pub e_o: f64,
    /// Torsional semi-axis (m).
    pub e_r: f64,
}

/// Dynamics of one body over the step at a trial end-of-step point.
///
/// The step's Newton–Euler rows use the mass matrix of the end of the step and the gyroscopic
/// impulse at the end-of-step angular velocity (the paper's `M^{u+1}`), so both depend on the
/// trial point; a backend that holds them fixed in a subproblem re-evaluates them at each outer
/// iterate (a fixed point whose limit satisfies the step's rows).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyDynamics {
    /// Generalised mass matrix `M = diag(m I₃, R I_body Rᵀ)` at the trial end-of-step
    /// orientation, row-major.
    pub mass: [[f64; 6]; 6],
    /// Free-motion velocity: the end-of-step velocity without contact impulses, with the
    /// applied, gravity and gyroscopic impulses as the step's Newton–Euler block discretises
    /// them, the gyroscopic impulse evaluated at the trial angular velocity.
    pub free_velocity: [f64; 6],
}

/// A vertex of Conv(F) near G at a trial configuration; for a contact between two hulls, a
/// vertex of the contact patch (a vertex of F over G, a vertex of G under F, or where an edge of
/// F crosses an edge of G, seen along the normal).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchVertex {
    /// Index of the vertex in the hull's vertex list (stable for the body's lifetime): the map
    /// back re-evaluates the vertex at the new configuration from it. For a contact between two
    /// hulls, an index the formulation decodes in the same way (which feature of which side).
    pub index: usize,
    /// World position at the trial configuration (on Conv(F)): F's lever arm.
    pub position: [f64; 3],
    /// Signed distance to G along the normal (positive outside G).
    pub gap: f64,
    /// The point of G facing `position` along the normal, `position − gap n` (G's lever arm;
    /// unused for a half-space).
    pub partner_position: [f64; 3],
}

/// The other side G of a contact.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum ContactPartner {
    /// A fixed half-space (the one-face case): no velocity, no impulse.
    #[default]
    HalfSpace,
    /// A dynamic body (in [`StepStructure::body`] numbering), with its centre of mass at the
    /// trial configuration: it receives the opposite impulse.
    Body {
        /// Index of the body.
        body: usize,
        /// Its centre of mass at the trial configuration.
        center_of_mass: [f64; 3],
    },
    /// A fixed or kinematic body: its velocity over the step is data (zero when fixed) and it
    /// receives no impulse.
    Prescribed {
        /// Its velocity `(v, ω)` over the step, `v` that of `center_of_mass`.
        velocity: [f64; 6],
        /// The reference point of `velocity` (its end-of-step position).
        center_of_mass: [f64; 3],
    },
}

/// One contact (Conv(F) of a body against a fixed half-space G, or against the convex hull of
/// another body) evaluated at a trial end-of-step configuration (`docs/model.md#contact`,
/// `docs/model.md#friction`, `docs/model.md#contact-between-two-bodies`).
#[derive(Clone, Debug, PartialEq)]
pub struct ContactGeometry {
    /// Index of the body (in [`StepStructure::body`] numbering).
    pub body: usize,
    /// Unit normal `n` of G pointing into F (for two hulls, the pair's normal `ν_G/|ν_G|` at the
    /// trial point).
    pub normal: [f64; 3],
    /// First unit tangent `t`.
    pub tangent: [f64; 3],
    /// Second unit tangent `o = n × t`.
    pub bitangent: [f64; 3],
    /// Centre of mass `x` at the trial configuration.
    pub center_of_mass: [f64; 3],
    /// Signed distance between Conv(F) and G: the smallest vertex gap over the whole hull.
    pub gap: f64,
    /// The vertices of Conv(F) in the tolerance band (see [`StepStructure::contact`]); the
    /// contact patch is the part of their convex hull that touches G.
    pub patch: Vec<PatchVertex>,
    /// The current equivalent contact point `a1` of the trial point.
    pub ecp: [f64; 3],
    /// Friction parameters.
    pub friction: ContactFriction,
    /// The other side: a half-space, a dynamic body or a body with prescribed velocity. The
    /// friction acts on the velocity of F relative to G at the ECP.
    pub partner: ContactPartner,
}

/// Impulses of one contact in a conic solution.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ContactImpulses {
    /// Normal impulses at patch vertices, `(vertex index, λ ≥ 0)`; their sum is `p_n` and their
    /// centre of pressure (at the end-of-step configuration) is the ECP `a1`.
    pub vertex_impulses: Vec<(usize, f64)>,
    /// Friction wrench `(p_t, p_o, p_r)`, applied at the ECP.
    pub friction: [f64; 3],
    /// Slip magnitude `σ ≥ 0` (`docs/model.md#friction`).
    pub sigma: f64,
    /// The normal the impulses were computed with (zero when the backend did not say): the map
    /// back of a contact between two hulls orients the pair's normal by it.
    pub normal: [f64; 3],
}

/// A point of a structure-exploiting backend: end-of-step velocities and contact impulses.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ConicPoint {
    /// End-of-step velocity `ν = (v, ω)` of every body.
    pub velocities: Vec<[f64; 6]>,
    /// Impulses of every contact, in [`StepStructure::contact`] numbering.
    pub contacts: Vec<ContactImpulses>,
}

/// What a structure-exploiting backend needs from a contact step (`docs/backends.md#conic`).
///
/// Implemented by the formulation crate for its time-step MCP; a backend reaches it through
/// [`crate::Mcp::structure`].
pub trait StepStructure {
    /// Step length `h`.
    fn step_length(&self) -> f64;
    /// Number of bodies.
    fn num_bodies(&self) -> usize;
    /// Mass matrix and free-motion velocity of body `b` at the trial end-of-step point stored in
    /// `z` (its orientation and angular velocity; see [`BodyDynamics`]).
    fn body(&self, b: usize, z: &[f64]) -> BodyDynamics;
    /// Number of contacts.
    fn num_contacts(&self) -> usize;
    /// The end-of-step velocities `ν` stored in the full MCP vector `z`.
    fn velocities(&self, z: &[f64]) -> Vec<[f64; 6]>;
    /// [`StepStructure::velocities`] into `out` (cleared first, its storage kept); the default
    /// calls `velocities`.
    fn velocities_into(&self, z: &[f64], out: &mut Vec<[f64; 6]>) {
        out.clear();
        out.extend(self.velocities(z));
    }
    /// Contact `c` at the end-of-step configuration `q` stored in `z` (with the ECP `a1` of `z`).
    ///
    /// The patch holds every vertex `j` of Conv(F) whose gap is at most
    /// `band + 2 h max(0, −ġ_j)`, with `ġ_j` the normal velocity of the vertex at the velocities
    /// of `z` or at the free-motion velocities, whichever approaches faster: vertices that may
    /// touch G within the step.
    fn contact(&self, c: usize, z: &[f64], band: f64) -> ContactGeometry;
    /// [`StepStructure::contact`] into `out`, whose storage (the patch's vector) an
    /// implementation may refill instead of allocating anew: a backend that keeps its contacts
    /// across iterations then allocates nothing (`docs/latency.md#allocations`). The same contact
    /// as `contact`; the default calls it.
    fn contact_into(&self, c: usize, z: &[f64], band: f64, out: &mut ContactGeometry) {
        *out = self.contact(c, z, band);
    }
    /// Maps a conic point back to the full MCP vector: `ν` as given; `q` by the kinematic map
    /// (`docs/model.md#kinematic-map`); per contact, with `p_n = Σ λ_j > 0`, `a1 = Σ λ_j v_j / p_n`
    /// at the new configuration, otherwise `a1` the point of Conv(F) nearest to G; `a2` the
    /// projection of `a1` on G; `l_g = max(g(a1), 0)`; the face multipliers `l ≥ 0` of the faces
    /// active at `a1` with `Σ l_i ∇f_i = −∇g` (non-negative least squares); `p_n`, `p_f`, `σ` as
    /// given. Every entry of `z` is overwritten.
    fn assemble(&self, point: &ConicPoint, z: &mut [f64]);
    /// The normal impulse `p_n` of contact `c` stored in `z` (a warm start carries the previous
    /// step's); `None` when the structure does not say. A backend may centre a proximal term
    /// on it (the conic backend's load anchor, `docs/latency.md#conic-backend`).
    fn normal_impulse(&self, _c: usize, _z: &[f64]) -> Option<f64> {
        None
    }
}
