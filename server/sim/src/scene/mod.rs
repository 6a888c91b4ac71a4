//! Scenes: what to simulate. A [`SceneSpec`] names the organ mesh (built-in or a file), the
//! material, how to sample the interior, which features the scene uses, the tool and the
//! force model. Built-in scenes are defined here in code; scene files (TOML) are read by
//! [`file`]. Everything is in SI units; the TOML keys carry their user-facing units (mm, kPa).

mod build;
pub mod file;
pub mod footprint;
pub mod real_time;
pub mod supports;

use std::path::PathBuf;

use serde::Serialize;

pub use build::{
    BuiltScene, PreparedSurface, SceneBuildError, build_model, build_scene, prepare_surface,
};
pub use file::SceneError;
pub use real_time::{PlannedSampling, SamplingPlan};
pub use supports::{Loads, Region, Supports};

use crate::geometry::organs;
use crate::geometry::remesh::POOR_ANGLE_DEG;
use crate::geometry::{ImportLimits, LengthUnit, MeshStats, TriMesh};
use crate::math::Vec3;
use crate::model::{SamplingParams, SpacingRule};

/// A complete, validated scene description.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SceneSpec {
    /// Short name.
    pub name: String,
    /// One line for listings.
    pub description: String,
    /// The organ surface.
    pub mesh: MeshSpec,
    /// Tissue material.
    pub material: Material,
    /// Interior sampling.
    pub sampling: SamplingParams,
    /// The stages and services the scene uses; everything else is left out.
    pub features: Features,
    /// The virtual scalpel.
    pub tool: ToolSpec,
    /// Cutting force model.
    pub force: ForceSpec,
    /// Numerical choices of the solver a scene may make.
    pub solver: SolverSpec,
    /// Gravity.
    pub loads: Loads,
    /// What holds the body.
    pub supports: Supports,
}

/// Numerical choices of the solver a scene may make (`[solver]` in a scene file).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SolverSpec {
    /// Mass the explicit solver may add, as a fraction of the body's, so that ticks take a
    /// whole sub-step fewer and keep that count through cuts (mass scaling: see
    /// `solver::whole_substeps` and `solver::kept_substeps`); 0 keeps the masses as built
    /// (the cap on fits a cut leaves degenerate is a matter of stability, not of this).
    pub mass_scaling_budget: f64,
    /// How ticks are integrated when the scene does not ask for the stiff mode.
    pub integrator: Integrator,
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            mass_scaling_budget: 0.01,
            integrator: Integrator::Explicit,
        }
    }
}

/// The dynamic integrator a scene chooses (`[solver] integrator`); the stiff mode
/// (`[features] stiff_mode`, projective dynamics) is the third.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// Symplectic Euler in sub-steps from the stable step (the default).
    Explicit,
    /// Linearly implicit Euler, one preconditioned CG solve per tick (`solver::implicit`).
    Implicit,
}

impl SceneSpec {
    /// Whether ticks are explicit sub-steps (what the sampling plan and the footprint's
    /// tick estimate know how to plan).
    pub fn is_explicit(&self) -> bool {
        !self.features.stiff_mode && self.solver.integrator == Integrator::Explicit
    }
}

/// Where the surface comes from and how it is placed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshSpec {
    /// Built-in shape or file.
    pub source: MeshSource,
    /// Units of the file's coordinates (ignored for built-in shapes, which are in metres).
    pub units: LengthUnit,
    /// Placement applied after unit conversion.
    pub transform: Transform,
    /// Size caps for files.
    pub limits: ImportLimits,
    /// Whether validation searches for self-intersections.
    pub check_self_intersections: bool,
    /// Whether the surface is remeshed to even triangles after validation.
    pub remesh: RemeshRule,
}

/// When a validated surface is remeshed ([`crate::geometry::remesh`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RemeshRule {
    /// Never: the triangles are used as they come.
    Off,
    /// When a triangle has an angle under 15° (the cutting code's own bound), to the
    /// smaller of the mean edge length and the volume-to-area ratio (half the mean
    /// thickness: a thin part keeps triangles narrower than itself), but no less than 0.4
    /// of the mean edge (at most about six times the triangles).
    Auto,
    /// Always, to edges of this length (m).
    EdgeM(f64),
}

impl RemeshRule {
    /// The edge length to remesh a surface with these measures to, if it is to be
    /// remeshed.
    pub fn target_for(self, stats: &MeshStats) -> Option<f64> {
        match self {
            Self::Off => None,
            Self::EdgeM(m) => Some(m),
            Self::Auto => (stats.min_angle_deg < POOR_ANGLE_DEG).then(|| {
                let half_thickness = stats.volume_m3.abs() / stats.area_m2;
                let edge = stats.mean_edge_m;
                edge.min(half_thickness).max(0.4 * edge)
            }),
        }
    }
}

/// The mesh source.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MeshSource {
    /// A procedural organ.
    Builtin(BuiltinMesh),
    /// A mesh file (path resolved against the scene file's folder).
    File(PathBuf),
}

/// Procedural organ shapes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BuiltinMesh {
    /// Liver, 250 × 150 × 50 mm, 508 triangles.
    Liver,
    /// Deltoid-like shoulder muscle, 1842 triangles.
    Shoulder,
    /// Brain tumour, 50 × 40 × 30 mm, 2600 triangles.
    Cerebroma,
    /// 30 mm cube.
    Block,
    /// 40 × 10 × 10 mm cantilever beam.
    Beam,
}

impl BuiltinMesh {
    /// All shapes, in listing order.
    pub const ALL: [BuiltinMesh; 5] = [
        Self::Liver,
        Self::Shoulder,
        Self::Cerebroma,
        Self::Block,
        Self::Beam,
    ];

    /// Name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Liver => "liver",
            Self::Shoulder => "shoulder",
            Self::Cerebroma => "cerebroma",
            Self::Block => "block",
            Self::Beam => "beam",
        }
    }

    /// Looks a shape up by name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|b| b.name() == name)
    }

    /// Generates the surface (m, centred on the origin).
    pub fn generate(self) -> TriMesh {
        match self {
            Self::Liver => organs::liver(),
            Self::Shoulder => organs::shoulder(),
            Self::Cerebroma => organs::cerebroma(),
            Self::Block => organs::box_mesh(Vec3::repeat(0.030), [6, 6, 6]),
            Self::Beam => organs::box_mesh(Vec3::new(0.040, 0.010, 0.010), [16, 4, 4]),
        }
    }
}

/// Scale, then rotate (x, then y, then z, about the origin), then translate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Transform {
    /// Per-axis scale factors.
    pub scale: [f64; 3],
    /// Rotation angles about x, y, z (degrees).
    pub rotate_deg: [f64; 3],
    /// Translation (m).
    pub translate_m: [f64; 3],
}

impl Default for Transform {
    fn default() -> Self {
        Self {
            scale: [1.0; 3],
            rotate_deg: [0.0; 3],
            translate_m: [0.0; 3],
        }
    }
}

impl Transform {
    /// True when applying it changes nothing.
    pub fn is_identity(&self) -> bool {
        *self == Self::default()
    }

    /// Applies the transform to a point.
    pub fn apply(&self, p: &Vec3) -> Vec3 {
        let r = self.rotate_deg.map(f64::to_radians);
        let rotation = nalgebra::Rotation3::from_euler_angles(r[0], r[1], r[2]);
        rotation * p.component_mul(&Vec3::from(self.scale)) + Vec3::from(self.translate_m)
    }

    /// True when the transform mirrors (an odd number of negative scales), which turns the
    /// surface inside out.
    pub fn mirrors(&self) -> bool {
        self.scale.iter().filter(|s| **s < 0.0).count() % 2 == 1
    }
}

/// Tissue material (St. Venant–Kirchhoff parameters plus damping).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Material {
    /// Young's modulus E (Pa).
    pub youngs_modulus_pa: f64,
    /// Poisson's ratio ν, in [0, 0.5).
    pub poisson_ratio: f64,
    /// Density ρ (kg/m³).
    pub density_kg_m3: f64,
    /// Mass-proportional damping γ (1/s): v ← v·e^(−γ dt).
    pub damping_per_s: f64,
    /// Strain-stiffening β (dimensionless, 0: none): the base law's energy ψ₀ becomes
    /// (E/2β)(e^Q − 1), Q = 2βψ₀/E — the same at small strain, about e^(βε²) stiffer at a
    /// stretch ε (docs/SCENES.md).
    pub stiffening: f64,
    /// Residual tension ε of the surface layer (dimensionless, 0: none): the layer's
    /// stress-free state is ε shorter in the surface's plane than the mesh
    /// (`mls::prestress`, docs/SCENES.md).
    pub prestrain: f64,
    /// How deep that layer reaches under the surface (m); `None`: one lattice spacing.
    pub prestrain_depth_m: Option<f64>,
}

impl Material {
    /// Liver: E = 5 kPa, ν = 0.45, ρ = 1060 kg/m³ (physics.md §6.3), linear at small
    /// strain; [`ORGAN_STIFFENING`] is the built-in organ's.
    pub const LIVER: Material = Material {
        youngs_modulus_pa: 5_000.0,
        poisson_ratio: 0.45,
        density_kg_m3: 1060.0,
        damping_per_s: 10.0,
        stiffening: 0.0,
        prestrain: 0.0,
        prestrain_depth_m: None,
    };
    /// Relaxed skeletal muscle (deltoid): E ≈ 10 kPa.
    pub const MUSCLE: Material = Material {
        youngs_modulus_pa: 10_000.0,
        poisson_ratio: 0.45,
        density_kg_m3: 1060.0,
        damping_per_s: 10.0,
        stiffening: 0.0,
        prestrain: 0.0,
        prestrain_depth_m: None,
    };
    /// Brain tissue around a tumour: E ≈ 3 kPa (physics.md §6.3: brain 1–3 kPa).
    pub const BRAIN: Material = Material {
        youngs_modulus_pa: 3_000.0,
        poisson_ratio: 0.45,
        density_kg_m3: 1040.0,
        damping_per_s: 10.0,
        stiffening: 0.0,
        prestrain: 0.0,
        prestrain_depth_m: None,
    };

    /// The same material, strain-stiffening by `beta`.
    pub const fn stiffening_by(self, beta: f64) -> Material {
        Material {
            stiffening: beta,
            ..self
        }
    }
}

/// The built-in organs' strain-stiffening β: liver, muscle and brain are quasi-linear at
/// small strain and stiffen steeply beyond (liver: exponential fits, Roan & Vemaganti 2007,
/// Capilnasiu et al. 2020; brain: Ogden fits with |α| ≈ 20, Budday et al. 2017; passive
/// muscle: exponential fits are the usual model). β = 10 makes the tangent about 7 times E
/// at a 30 % stretch; chosen to that shape, not fitted to one organ's curve
/// (docs/CUTTING-DECISIONS.md, "Cutting parameters for each organ").
pub const ORGAN_STIFFENING: f64 = 10.0;

/// Fracture toughness J_c of liver cut with a blade (N/m = J/m²): 187–225 J/m²
/// (Chanthasopeephan et al. 2003 via cutting-physics.md §3).
pub const LIVER_TOUGHNESS_N_PER_M: f64 = 190.0;
/// Fracture toughness of skeletal muscle cut with a blade (J/m²): no blade measurement of
/// muscle is known to us; fibrous soft tissues cut with a blade measure 170–450 J/m²
/// (porcine aorta 290 ± 110, lamina propria 169–451), far below the notched-test figures
/// for porcine muscle (550–8000 J/m²) that Taylor et al. 2012 show measure strength, not
/// toughness (docs/CUTTING-DECISIONS.md, "Cutting parameters for each organ").
pub const MUSCLE_TOUGHNESS_N_PER_M: f64 = 300.0;
/// Fracture toughness of brain (J/m²): cutting-physics.md §3's 10–50 J/m², the middle of
/// it (wire cutting and cavitation report 1.5–9 J/m² at low rates, rising with the rate:
/// Terzano et al. 2021; Dougan et al.'s needle-induced cavitation).
pub const BRAIN_TOUGHNESS_N_PER_M: f64 = 30.0;

/// What a scene uses. The pipeline builds only these stages and the server starts only
/// these services ("leave out what a scene does not need").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct Features {
    /// Blade cutting (incision, internal cut, force model).
    pub cutting: bool,
    /// A haptic device loop at 1 kHz.
    pub haptics: bool,
    /// Virtual points along incisions (needs cutting).
    pub virtual_points: bool,
    /// Force ripple after rupture (needs cutting).
    pub ripple: bool,
    /// Müller's volume-conservation term.
    pub volume_term: bool,
    /// Stiff-material integrator instead of explicit sub-stepping.
    pub stiff_mode: bool,
    /// Render frames to local viewers.
    pub frames: bool,
    /// A network endpoint for remote observers.
    pub observers: bool,
}

impl Features {
    /// Everything a cutting station uses.
    pub const CUTTING_STATION: Features = Features {
        cutting: true,
        haptics: true,
        virtual_points: true,
        ripple: true,
        volume_term: false,
        stiff_mode: false,
        frames: true,
        observers: false,
    };

    /// The enabled features by name, for reports.
    pub fn enabled(&self) -> Vec<&'static str> {
        [
            (self.cutting, "cutting"),
            (self.haptics, "haptics"),
            (self.virtual_points, "virtual_points"),
            (self.ripple, "ripple"),
            (self.volume_term, "volume_term"),
            (self.stiff_mode, "stiff_mode"),
            (self.frames, "frames"),
            (self.observers, "observers"),
        ]
        .into_iter()
        .filter_map(|(on, name)| on.then_some(name))
        .collect()
    }
}

/// The virtual scalpel's blade (paper §4.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ToolSpec {
    /// Length of the cutting edge (m).
    pub blade_length_m: f64,
    /// Width of the blade from edge to back (m).
    pub blade_width_m: f64,
    /// Blade thickness (m).
    pub blade_thickness_m: f64,
}

impl Default for ToolSpec {
    fn default() -> Self {
        // A No. 10 scalpel blade: ~25 mm edge, ~8 mm wide, 0.4 mm thick.
        Self {
            blade_length_m: 0.025,
            blade_width_m: 0.008,
            blade_thickness_m: 0.0004,
        }
    }
}

/// Cutting force model (paper eqs. 17–19 as reinterpreted in physics.md §6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ForceSpec {
    /// Peak force before the capsule ruptures, F_r (N).
    pub rupture_force_n: f64,
    /// Blade travel at rupture, x_r (m).
    pub rupture_displacement_m: f64,
    /// Fracture toughness J_c per unit depth (N/m); 190 J/m² = 0.19 N/mm for liver.
    pub toughness_n_per_m: f64,
    /// The crack advances by energy at its front and the cutting force is the tissue's
    /// (cutting-physics.md §3): experimental, off by default until the blade's flats hold
    /// the lips (docs/CUTTING-DECISIONS.md, "Fracture by energy, first trial"). Off, the
    /// crack follows the blade and the force is J_c·w + friction + ripple.
    pub fracture_by_energy: bool,
    /// How much stiffer than E the tissue at the crack tip is (its strain-stiffening, ≥ 1):
    /// the crack advances in jumps of the process zone's length J_c / (c·E), the period of
    /// the cutting force's sawtooth (cutting-physics.md §3; docs/CUTTING.md, "The force").
    pub crack_tip_stiffening: f64,
    /// Friction on the blade while cutting (N), reached at `friction_depth_m`.
    pub friction_n: f64,
    /// Cut depth at which the friction reaches `friction_n` (m); a shallower blade rubs on
    /// less tissue, and friction grows with the contact area, so in proportion to depth.
    pub friction_depth_m: f64,
    /// Ripple amplitude ε as a fraction of the mean force.
    pub ripple_amplitude: f64,
    /// Ripple wavelength λ in blade travel (m).
    pub ripple_wavelength_m: f64,
    /// Ripple decay time τ_d (s).
    pub ripple_decay_s: f64,
    /// κ of the transparency zone at the crack front (physics.md §4.3): a pair crossing the
    /// cut within κh/2 of the blade's edge fades out instead of switching off; 0 is hard
    /// visibility.
    pub crack_transparency: f64,
    /// How far the tip (smoothed over 10 ms) must move from where it last moved to before
    /// the move counts as the blade's motion (m): the direction of the resistance, the
    /// crack's travel and ripple, the growth of Σ and the press direction follow the tip on
    /// a leash this long, so a device's position noise (a Geomagic Touch or a Falcon at
    /// rest: ±1 encoder count, ≈ 0.06 mm per axis) or a hand's tremor held still in a cut
    /// is not cutting. 0: the smoothed tip itself (`pipeline::steady_motion`).
    pub motion_deadband_m: f64,
    /// Largest force ever sent to a device (N).
    pub max_force_n: f64,
}

impl Default for ForceSpec {
    fn default() -> Self {
        Self {
            rupture_force_n: 3.0,
            rupture_displacement_m: 0.00317,
            toughness_n_per_m: LIVER_TOUGHNESS_N_PER_M,
            fracture_by_energy: false,
            // 2 mm jumps on the liver (E = 5 kPa, J_c = 190 J/m²).
            crack_tip_stiffening: 19.0,
            friction_n: 0.3,
            friction_depth_m: 0.010,
            ripple_amplitude: 0.15,
            ripple_wavelength_m: 0.002,
            ripple_decay_s: 1.0,
            crack_transparency: 1.0,
            motion_deadband_m: 0.0001,
            // Geomagic Touch peak rating (physics.md §7.5).
            max_force_n: 3.3,
        }
    }
}

/// Names of the built-in scenes, in listing order.
pub const BUILTIN_SCENES: [&str; 5] = ["liver", "shoulder", "cerebroma", "block", "beam"];

/// The built-in scene called `name`.
pub fn builtin(name: &str) -> Option<SceneSpec> {
    let shape = BuiltinMesh::from_name(name)?;
    let (description, material, spacing, features) = match shape {
        BuiltinMesh::Liver => (
            "liver, 250 × 150 × 50 mm, 508 triangles, ~1526 points (paper Table 1)",
            Material::LIVER.stiffening_by(ORGAN_STIFFENING),
            SpacingRule::TargetPoints(1526),
            Features::CUTTING_STATION,
        ),
        BuiltinMesh::Shoulder => (
            "shoulder muscle (deltoid-like), 1842 triangles, ~4812 points (paper Table 1)",
            Material::MUSCLE.stiffening_by(ORGAN_STIFFENING),
            SpacingRule::TargetPoints(4812),
            Features::CUTTING_STATION,
        ),
        BuiltinMesh::Cerebroma => (
            "brain tumour, 50 × 40 × 30 mm, 2600 triangles, ~7086 points (paper Table 1)",
            Material::BRAIN.stiffening_by(ORGAN_STIFFENING),
            SpacingRule::TargetPoints(7086),
            Features::CUTTING_STATION,
        ),
        BuiltinMesh::Block => (
            "30 mm cube of liver tissue, 3 mm lattice, for validation",
            Material::LIVER,
            SpacingRule::Spacing(0.003),
            Features::default(),
        ),
        BuiltinMesh::Beam => (
            "40 × 10 × 10 mm cantilever, 5 points across, for validation",
            Material::LIVER,
            SpacingRule::Spacing(0.0025),
            Features::default(),
        ),
    };
    Some(SceneSpec {
        name: name.to_string(),
        description: description.to_string(),
        mesh: MeshSpec {
            source: MeshSource::Builtin(shape),
            units: LengthUnit::M,
            transform: Transform::default(),
            limits: ImportLimits::default(),
            check_self_intersections: true,
            remesh: RemeshRule::Auto,
        },
        material,
        sampling: SamplingParams {
            spacing,
            ..SamplingParams::default()
        },
        features,
        tool: ToolSpec::default(),
        force: ForceSpec {
            toughness_n_per_m: match shape {
                BuiltinMesh::Shoulder => MUSCLE_TOUGHNESS_N_PER_M,
                BuiltinMesh::Cerebroma => BRAIN_TOUGHNESS_N_PER_M,
                _ => LIVER_TOUGHNESS_N_PER_M,
            },
            ..ForceSpec::default()
        },
        solver: SolverSpec::default(),
        // The organs rest on their supports under standard gravity; the validation bodies
        // keep their analytic conditions.
        loads: match shape {
            BuiltinMesh::Block | BuiltinMesh::Beam => Loads::default(),
            _ => Loads {
                gravity: supports::STANDARD_GRAVITY,
            },
        },
        supports: match shape {
            BuiltinMesh::Liver => supports::anatomical::liver(),
            BuiltinMesh::Shoulder => supports::anatomical::shoulder(),
            BuiltinMesh::Cerebroma => supports::anatomical::cerebroma(),
            BuiltinMesh::Block | BuiltinMesh::Beam => Supports::default(),
        },
    })
}

/// Scene settings for a bare mesh file: liver material, 2000 target points, no features
/// beyond deformation.
pub fn for_mesh_file(path: PathBuf, units: LengthUnit) -> SceneSpec {
    let name = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("mesh")
        .to_string();
    SceneSpec {
        description: format!("mesh file {}", path.display()),
        name,
        mesh: MeshSpec {
            source: MeshSource::File(path),
            units,
            transform: Transform::default(),
            limits: ImportLimits::default(),
            check_self_intersections: true,
            remesh: RemeshRule::Auto,
        },
        material: Material::LIVER,
        sampling: SamplingParams::default(),
        features: Features::default(),
        tool: ToolSpec::default(),
        force: ForceSpec::default(),
        solver: SolverSpec::default(),
        loads: Loads::default(),
        supports: Supports::default(),
    }
}
