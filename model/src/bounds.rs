//! Variable blocks and their bounds (`docs/model.md#mcp`: the PATH/GAMS box convention).

use crate::error::ModelError;

/// Bounds of one scalar unknown: `lower ≤ z ≤ upper`, entries may be ±∞.
///
/// The kind of bound decides which complementarity condition the paired residual obeys
/// (`docs/model.md#mcp`): free ⇒ equation, lower only ⇒ `0 ≤ z − l ⊥ F ≥ 0`, and so on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Lower bound, `-∞` for none.
    pub lower: f64,
    /// Upper bound, `+∞` for none.
    pub upper: f64,
}

/// What kind of bound a component has; backends reformulate each kind differently.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoundKind {
    /// `-∞ < z < ∞`: the paired residual is an equation.
    Free,
    /// `l ≤ z`, no upper bound.
    Lower,
    /// `z ≤ u`, no lower bound.
    Upper,
    /// `l ≤ z ≤ u`, both finite (possibly `l = u`).
    Box,
}

impl Bounds {
    /// No bounds: the paired residual is an equation.
    pub const FREE: Bounds = Bounds {
        lower: f64::NEG_INFINITY,
        upper: f64::INFINITY,
    };
    /// `z ≥ 0`: the usual complementarity variable.
    pub const NONNEGATIVE: Bounds = Bounds {
        lower: 0.0,
        upper: f64::INFINITY,
    };

    /// `z ≥ lower`.
    pub fn lower(lower: f64) -> Self {
        Bounds {
            lower,
            upper: f64::INFINITY,
        }
    }
    /// `z ≤ upper`.
    pub fn upper(upper: f64) -> Self {
        Bounds {
            lower: f64::NEG_INFINITY,
            upper,
        }
    }
    /// `lower ≤ z ≤ upper`.
    pub fn boxed(lower: f64, upper: f64) -> Self {
        Bounds { lower, upper }
    }

    /// Classifies the bound pair.
    pub fn kind(&self) -> BoundKind {
        classify(self.lower, self.upper)
    }

    /// Checks that the pair is meaningful: no NaN, `lower ≤ upper`, `lower < +∞`, `upper > -∞`.
    pub fn validate(&self) -> Result<(), String> {
        if self.lower.is_nan() || self.upper.is_nan() {
            return Err("a bound is NaN".into());
        }
        if self.lower > self.upper {
            return Err(format!(
                "lower bound {} exceeds upper bound {}",
                self.lower, self.upper
            ));
        }
        if self.lower == f64::INFINITY || self.upper == f64::NEG_INFINITY {
            return Err(
                "the feasible interval is empty (a bound is infinite on the wrong side)".into(),
            );
        }
        Ok(())
    }
}

/// Classifies a bound pair given as two numbers.
pub fn classify(lower: f64, upper: f64) -> BoundKind {
    match (lower.is_finite(), upper.is_finite()) {
        (false, false) => BoundKind::Free,
        (true, false) => BoundKind::Lower,
        (false, true) => BoundKind::Upper,
        (true, true) => BoundKind::Box,
    }
}

/// Handle of a variable block inside a [`Problem`](crate::Problem).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VarId(pub usize);

/// A named block of unknowns with per-component bounds, like a Ceres parameter block.
///
/// Each variable block is paired with exactly one residual block of the same length
/// (`docs/model.md#mcp`, `docs/model.md#unknowns`).
#[derive(Clone, Debug)]
pub struct VarBlock {
    name: String,
    bounds: Vec<Bounds>,
    component_names: Option<Vec<String>>,
}

impl VarBlock {
    /// A block whose components all have the same bounds.
    pub fn new(name: impl Into<String>, size: usize, bounds: Bounds) -> Self {
        VarBlock {
            name: name.into(),
            bounds: vec![bounds; size],
            component_names: None,
        }
    }
    /// A block of free variables (paired with equations).
    pub fn free(name: impl Into<String>, size: usize) -> Self {
        Self::new(name, size, Bounds::FREE)
    }
    /// A block of nonnegative variables (paired with complementarity conditions).
    pub fn nonnegative(name: impl Into<String>, size: usize) -> Self {
        Self::new(name, size, Bounds::NONNEGATIVE)
    }
    /// A block with individual bounds per component.
    pub fn with_bounds(name: impl Into<String>, bounds: Vec<Bounds>) -> Self {
        VarBlock {
            name: name.into(),
            bounds,
            component_names: None,
        }
    }
    /// Names the components (for diagnostics such as "worst residual at nu.wz").
    pub fn with_component_names<S: Into<String>>(
        mut self,
        names: impl IntoIterator<Item = S>,
    ) -> Self {
        self.component_names = Some(names.into_iter().map(Into::into).collect());
        self
    }
    /// The block's name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Number of components.
    pub fn size(&self) -> usize {
        self.bounds.len()
    }
    /// Bounds per component.
    pub fn bounds(&self) -> &[Bounds] {
        &self.bounds
    }
    /// Name of component `i`: `block.component` or `block[i]`.
    pub fn component_name(&self, i: usize) -> String {
        let mut name = String::new();
        self.write_component_name(i, &mut name);
        name
    }
    /// Appends [`VarBlock::component_name`] of `i` to `out`.
    pub fn write_component_name(&self, i: usize, out: &mut String) {
        use std::fmt::Write;
        match &self.component_names {
            // Pieces pushed, not formatted: the finish of every solve names its worst component
            // (`write!` through the formatting machinery was ≈ 0.4 k instructions of it).
            Some(names) if i < names.len() => {
                out.push_str(&self.name);
                out.push('.');
                out.push_str(&names[i]);
            }
            // Writing into a String cannot fail.
            _ => _ = write!(out, "{}[{}]", self.name, i),
        }
    }

    pub(crate) fn validate(&self) -> Result<(), ModelError> {
        if let Some(names) = &self.component_names
            && names.len() != self.size()
        {
            return Err(ModelError::InvalidBlock {
                block: self.name.clone(),
                reason: format!(
                    "{} component names given for {} components",
                    names.len(),
                    self.size()
                ),
            });
        }
        for (i, b) in self.bounds.iter().enumerate() {
            b.validate().map_err(|reason| ModelError::InvalidBlock {
                block: self.name.clone(),
                reason: format!("component {i}: {reason}"),
            })?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A component's name is `block.component` when named, `block[i]` otherwise, appended to
    /// what the string held.
    #[test]
    fn component_names_are_block_dot_name_or_block_index() {
        let named = VarBlock::free("box.nu", 3).with_component_names(["vx", "vy", "wz"]);
        assert_eq!(named.component_name(2), "box.nu.wz");
        let mut out = String::from("worst: ");
        named.write_component_name(0, &mut out);
        assert_eq!(out, "worst: box.nu.vx");
        let plain = VarBlock::nonnegative("contact.sigma", 12);
        assert_eq!(plain.component_name(11), "contact.sigma[11]");
        // Fewer names than components: the others by index.
        let short = VarBlock::free("q", 4).with_component_names(["w"]);
        assert_eq!(
            (short.component_name(0), short.component_name(3)),
            ("q.w".into(), "q[3]".into())
        );
    }
}
