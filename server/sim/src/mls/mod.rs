//! Meshless elasticity on the interior points (Müller-style MLS, corrected per
//! physics.md §1): the precomputed gradient operator with rank handling, constitutive
//! models, and forces as the exact negative energy gradient with hourglass stabilisation.

pub mod forces;
pub mod material;
pub mod operator;
pub mod prestress;

pub use forces::{ForceStats, add_elastic_forces, hourglass_stiffness, stiffness_product};
pub use material::{ElasticModel, ElasticParams, Lame};
pub use operator::{MlsOperator, PointRank, RankCounts};
pub use prestress::Prestress;
