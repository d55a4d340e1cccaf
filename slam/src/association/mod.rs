//! Data association: which observation belongs to which mapped landmark.
//!
//! Position-only baselines ([`nn`], [`jcbb`]) beside the paper's appearance-based methods
//! (`appearance`: KL only; `combined`: a Mahalanobis gate on position, then KL).

pub mod jcbb;
pub mod nn;

use serde::{Deserialize, Serialize};

/// The association methods, by their configuration names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AssociationMethod {
    /// Position-only nearest neighbour with a chi-square gate.
    Nn,
    /// Position-only joint compatibility branch and bound (Neira & Tardos 2001).
    Jcbb,
    /// Appearance-only: the KL divergence between object models decides.
    Appearance,
    /// The paper's method: a position gate selects candidates, the KL divergence decides.
    #[default]
    Combined,
}

impl AssociationMethod {
    pub const ALL: [AssociationMethod; 4] =
        [AssociationMethod::Combined, AssociationMethod::Nn, AssociationMethod::Jcbb, AssociationMethod::Appearance];

    pub fn name(self) -> &'static str {
        match self {
            AssociationMethod::Nn => "nn",
            AssociationMethod::Jcbb => "jcbb",
            AssociationMethod::Appearance => "appearance",
            AssociationMethod::Combined => "combined",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Whether the method needs camera images and appearance models.
    pub fn uses_appearance(self) -> bool {
        matches!(self, AssociationMethod::Appearance | AssociationMethod::Combined)
    }
}

/// A candidate landmark considered for an observation, with its scores.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    pub landmark: u32,
    /// Squared Mahalanobis distance of the position.
    pub mahalanobis2: f64,
    /// KL divergence of the appearance models, when computed.
    pub kl: Option<f64>,
}

/// What was decided for an observation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Choice {
    /// Associated with this existing landmark.
    Existing { landmark: u32 },
    /// Started a new landmark.
    New { landmark: u32 },
    /// Neither: too ambiguous to associate or to create.
    Rejected,
    /// Neither, for now: the KL test found no match, but a confirmed landmark that looks
    /// alike lies within the new-landmark gate (the pose is too uncertain to tell a new
    /// object from that one). Later observations decide.
    Deferred,
}

/// One association decision, for the log the scorer reads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AssociationDecision {
    pub t: f64,
    /// Index of the observation within its scan.
    pub observation: usize,
    pub candidates: Vec<Candidate>,
    pub choice: Choice,
    pub method: AssociationMethod,
}

/// Upper quantile of the chi-square distribution with `dof` degrees of freedom at
/// probability `p`: exact for 2 dof (the individual gates), else by the Wilson-Hilferty
/// approximation. Against scipy's exact quantiles over 3..40 dof it is within 0.6% at 0.95
/// and 0.99 and within 1.8% at 0.999 (worst at 3 dof); for the joint tests' even 4..40 dof
/// at 0.99, within 0.22%. Where no quantile exists (`dof` 0, `p` outside [0, 1)) it
/// returns [`Chi2DomainError`].
pub fn chi2_quantile(dof: usize, p: f64) -> Result<f64, Chi2DomainError> {
    if !(dof >= 1 && (0.0..1.0).contains(&p)) {
        return Err(Chi2DomainError { dof, p });
    }
    Ok(chi2_quantile_in_domain(dof, p))
}

/// A chi-square quantile asked for where none exists.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[non_exhaustive]
#[error("no chi-square quantile at {dof} degrees of freedom and probability {p}: need dof >= 1 and 0 <= p < 1")]
pub struct Chi2DomainError {
    pub dof: usize,
    pub p: f64,
}

/// Why the pipeline's gates have a quantile: their probabilities are settings checked to
/// lie in (0, 1), at 2 degrees of freedom.
pub(crate) const CHECKED_GATE: &str = "gate probabilities are checked to lie in (0, 1)";

/// [`chi2_quantile`] for `dof >= 1` and `p` in [0, 1).
fn chi2_quantile_in_domain(dof: usize, p: f64) -> f64 {
    if dof == 2 {
        // Exact: the 2-dof chi-square is exponential.
        return -2.0 * (1.0 - p).ln();
    }
    let k = dof as f64;
    let z = normal_quantile(p);
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// Standard normal quantile (Acklam's rational approximation, relative error < 1.2e-9).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] =
        [-5.447609879822406e1, 1.615858368580409e2, -1.556989798598866e2, 6.680131188771972e1, -1.328068155288572e1];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let plow = 0.02425;
    if p < plow {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - plow {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_quantiles_match_tables() {
        // Reference values from standard chi-square tables.
        for (dof, p, exact) in [
            (2, 0.95, 5.991),
            (2, 0.99, 9.210),
            (2, 0.999, 13.816),
            (4, 0.99, 13.277),
            (10, 0.99, 23.209),
            (20, 0.95, 31.410),
        ] {
            let approx = chi2_quantile(dof, p).unwrap();
            assert!((approx - exact).abs() / exact < 0.01, "{dof} dof at {p}: {approx} vs {exact}");
        }
    }

    #[test]
    fn method_names_round_trip() {
        for m in AssociationMethod::ALL {
            assert_eq!(AssociationMethod::from_name(m.name()), Some(m));
        }
        assert_eq!(AssociationMethod::default(), AssociationMethod::Combined);
    }
}
