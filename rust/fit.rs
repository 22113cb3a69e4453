//! Fitting the elastic model through a sequence of target shapes (SPEC 5; the paper's
//! section 4): per iteration the rotations, the anisotropic surface-distance term with
//! confidence weights and invalidated associations, the self-intersection term, and one
//! sparse solve of $(\alpha S + \beta W + \gamma I)\,x = \alpha f + \beta W t + \gamma I x'$.

pub mod contact;
pub mod surface;

#[cfg(test)]
mod tests;
