//! What holds a body and what loads it (cutting-physics.md §1): gravity, fixed regions,
//! elastic attachments and a tray. A scene file gives them in `[loads]` and `[supports]`
//! (docs/SCENES.md); regions are in the scene's coordinates or as fractions of the body's
//! bounding box, so a built-in organ's supports follow it when a file moves or scales it.

use serde::Serialize;

use crate::math::{Aabb, Vec3};

/// Standard gravity (m/s²), down the scene's −z.
pub const STANDARD_GRAVITY: Vec3 = Vec3::new(0.0, 0.0, -9.81);

/// The loads on a body.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Loads {
    /// Gravitational acceleration (m/s²); zero for none.
    pub gravity: Vec3,
}

impl Default for Loads {
    fn default() -> Self {
        Self {
            gravity: Vec3::zeros(),
        }
    }
}

/// A region of the body, for a support.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Region {
    /// Inside an axis-aligned box (m, scene coordinates).
    Box {
        /// Low corner.
        min: [f64; 3],
        /// High corner.
        max: [f64; 3],
    },
    /// Inside a box given as fractions of the body's bounding box (0 its low side, 1 its
    /// high side, per axis).
    BoxFraction {
        /// Low corner.
        min: [f64; 3],
        /// High corner.
        max: [f64; 3],
    },
    /// On the side of a plane its normal points to (m, scene coordinates).
    BeyondPlane {
        /// A point of the plane.
        point: [f64; 3],
        /// Unit normal.
        normal: [f64; 3],
    },
    /// Within `radius` of a line (m, scene coordinates): a bone the tissue lies on.
    InsideCylinder {
        /// A point of the axis.
        point: [f64; 3],
        /// Unit direction of the axis.
        axis: [f64; 3],
        /// Radius (m).
        radius: f64,
    },
}

impl Region {
    /// Whether `x` lies in the region of a body whose bounding box is `body`.
    pub fn contains(&self, x: &Vec3, body: &Aabb) -> bool {
        match *self {
            Region::Box { min, max } => (0..3).all(|a| x[a] >= min[a] && x[a] <= max[a]),
            Region::BoxFraction { min, max } => (0..3).all(|a| {
                let span = body.max[a] - body.min[a];
                let f = if span > 0.0 {
                    (x[a] - body.min[a]) / span
                } else {
                    0.5
                };
                f >= min[a] && f <= max[a]
            }),
            Region::BeyondPlane { point, normal } => {
                (x - Vec3::from(point)).dot(&Vec3::from(normal)) >= 0.0
            }
            Region::InsideCylinder {
                point,
                axis,
                radius,
            } => {
                let (d, a) = (x - Vec3::from(point), Vec3::from(axis));
                (d - a * d.dot(&a)).norm() <= radius
            }
        }
    }
}

/// Surface tied to its rest place by springs: a ligament, the tissue around a tumour.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Attachment {
    /// The surface vertices it holds.
    pub region: Region,
    /// Stiffness per area (Pa/m): a vertex with area share A pulls back with k·A·|x − X|.
    pub stiffness_pa_per_m: f64,
}

/// A rigid plane the body rests on: unilateral contact with Coulomb friction on samples
/// of the surface.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Tray {
    /// Unit normal, out of the tray toward the body.
    pub normal: [f64; 3],
    /// A point of the tray's plane (m); `None`: touching the body's lowest surface point
    /// along the normal.
    pub point: Option<[f64; 3]>,
    /// Coulomb friction coefficient.
    pub friction: f64,
    /// Penalty stiffness per area (Pa/m) holding the surface out of the tray.
    pub stiffness_pa_per_m: f64,
}

/// Default tray and attachment stiffness per area: 1 kPa/mm, the soft end of
/// cutting-physics.md §1's 1–10 kPa/mm for ligaments. At 5 kPa/mm the liver's large
/// surface triangles (≈ 136 mm² a vertex) made its stable step 1.27 ms and every tick two
/// sub-steps (docs/BENCHMARKS.md, issue 40).
pub const DEFAULT_STIFFNESS_PA_PER_M: f64 = 1.0e6;

/// Wet tissue on steel.
pub const DEFAULT_TRAY_FRICTION: f64 = 0.2;

/// What holds the body.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct Supports {
    /// Points inside any of these are fixed at their rest places.
    pub fixed: Vec<Region>,
    /// Elastic attachments of surface regions.
    pub attachments: Vec<Attachment>,
    /// A tray under the body.
    pub tray: Option<Tray>,
}

impl Supports {
    /// Whether nothing holds the body.
    pub fn is_empty(&self) -> bool {
        self.fixed.is_empty() && self.attachments.is_empty() && self.tray.is_none()
    }

    /// Whether every fixed region holds a point (of `points`) and every attachment a
    /// surface vertex (of `vertices`), in the surface's bounding box; says which does not.
    pub fn check_holds(&self, points: &[Vec3], vertices: &[Vec3]) -> Result<(), String> {
        let body = Aabb::around(vertices);
        for (k, region) in self.fixed.iter().enumerate() {
            if !points.iter().any(|x| region.contains(x, &body)) {
                return Err(format!("supports.fixed[{k}] holds no point of the body"));
            }
        }
        for (k, a) in self.attachments.iter().enumerate() {
            if !vertices.iter().any(|x| a.region.contains(x, &body)) {
                return Err(format!(
                    "supports.attachments[{k}] holds no vertex of the surface"
                ));
            }
        }
        Ok(())
    }

    /// Why a body under `gravity` held only by these would not stay put, if it would not:
    /// nothing holds it, or it rests only on a tray steeper than its friction holds.
    pub fn unable_to_hold(&self, gravity: &Vec3) -> Option<String> {
        if gravity.norm() == 0.0 || !self.fixed.is_empty() || !self.attachments.is_empty() {
            return None;
        }
        let Some(tray) = &self.tray else {
            return Some(
                "gravity is on but nothing holds the body: add [supports] fixed regions, \
                 attachments or a tray, or set [loads] gravity_m_s2 = [0, 0, 0]"
                    .to_string(),
            );
        };
        let n = Vec3::from(tray.normal);
        let pressing = -gravity.dot(&n);
        let sliding = (gravity + n * pressing).norm();
        if pressing <= 0.0 {
            return Some(
                "gravity pulls the body off its tray and nothing else holds it: turn the \
                 tray's normal against gravity or add fixed regions or attachments"
                    .to_string(),
            );
        }
        (sliding > tray.friction * pressing).then(|| {
            format!(
                "the body would slide off its tray: the tray is tilted {:.1}° from level \
                 and friction {} holds at most {:.1}°; add fixed regions or attachments",
                sliding.atan2(pressing).to_degrees(),
                tray.friction,
                tray.friction.atan().to_degrees()
            )
        })
    }
}

/// How a body came to rest under gravity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SettleReport {
    /// Mean displacement of the points along gravity (mm).
    pub sag_mm: f64,
    /// Largest displacement of any point (mm).
    pub max_displacement_mm: f64,
    /// Simulated time to rest (s).
    pub settle_s: f64,
    /// Largest out-of-balance force on a point at the end, from its last tick's change of
    /// momentum (N).
    pub residual_n: f64,
    /// Whether it came to rest within the time allowed.
    pub settled: bool,
    /// Tray samples on the tray at the end.
    pub on_tray: usize,
    /// Newton iterations of a static settle (0 for a dynamic one).
    pub newton_iterations: u32,
}

/// Where a scene under gravity starts: its points at rest on its supports, found once per
/// built scene (`pipeline::Simulation::new`).
#[derive(Debug, Clone, PartialEq)]
pub struct StartState {
    /// The body's points (m).
    pub positions: Vec<Vec3>,
    /// The surface's vertices placed by the points (m).
    pub surface: Vec<Vec3>,
    /// How it came to rest.
    pub report: SettleReport,
}

/// The built-in organs' anatomical supports, in fractions of their bounding boxes: the
/// liver on a tray and held at its ligament side (its +x end); the tumour attached on its
/// deep half (the brain around it); the shoulder muscle fixed on its deep face (the bone).
pub mod anatomical {
    use super::*;

    /// The liver: on a tray, its ligament side (the +x tenth) attached.
    pub fn liver() -> Supports {
        Supports {
            fixed: Vec::new(),
            attachments: vec![Attachment {
                region: Region::BoxFraction {
                    min: [0.9, 0.0, 0.0],
                    max: [1.0, 1.0, 1.0],
                },
                stiffness_pa_per_m: DEFAULT_STIFFNESS_PA_PER_M,
            }],
            tray: Some(Tray {
                normal: [0.0, 0.0, 1.0],
                point: None,
                friction: DEFAULT_TRAY_FRICTION,
                stiffness_pa_per_m: DEFAULT_STIFFNESS_PA_PER_M,
            }),
        }
    }

    /// The cerebroma: its deep (lower) half attached to the brain around it.
    pub fn cerebroma() -> Supports {
        Supports {
            fixed: Vec::new(),
            attachments: vec![Attachment {
                region: Region::BoxFraction {
                    min: [0.0, 0.0, 0.0],
                    max: [1.0, 1.0, 0.5],
                },
                stiffness_pa_per_m: DEFAULT_STIFFNESS_PA_PER_M,
            }],
            tray: None,
        }
    }

    /// The shoulder muscle: its deep layer fixed to the bone it is draped over. The sheet
    /// is bent round an axis along y through (−32.4, 0, 0) mm (fitted to the built-in
    /// mesh: its vertices lie 49.7–77.6 mm from it, the mid-surface at 65); the points
    /// within 56 mm of it are the deep layer.
    pub fn shoulder() -> Supports {
        Supports {
            fixed: vec![Region::InsideCylinder {
                point: [-0.0324, 0.0, 0.0],
                axis: [0.0, 1.0, 0.0],
                radius: 0.056,
            }],
            attachments: Vec::new(),
            tray: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_hold_what_they_say() {
        let body = Aabb {
            min: [0.0, 0.0, 0.0],
            max: [0.2, 0.1, 0.05],
        };
        let deep = Region::BoxFraction {
            min: [0.0, 0.0, 0.0],
            max: [1.0, 1.0, 0.5],
        };
        assert!(deep.contains(&Vec3::new(0.1, 0.05, 0.02), &body));
        assert!(!deep.contains(&Vec3::new(0.1, 0.05, 0.03), &body));
        let plane = Region::BeyondPlane {
            point: [0.15, 0.0, 0.0],
            normal: [1.0, 0.0, 0.0],
        };
        assert!(plane.contains(&Vec3::new(0.16, 0.0, 0.0), &body));
        assert!(!plane.contains(&Vec3::new(0.14, 0.0, 0.0), &body));
    }

    #[test]
    fn a_body_with_gravity_must_be_held() {
        let g = STANDARD_GRAVITY;
        assert!(Supports::default().unable_to_hold(&g).is_some());
        assert!(Supports::default().unable_to_hold(&Vec3::zeros()).is_none());
        assert!(anatomical::liver().unable_to_hold(&g).is_none());
        let tray = |normal: [f64; 3]| Supports {
            tray: Some(Tray {
                normal,
                point: None,
                friction: 0.2,
                stiffness_pa_per_m: DEFAULT_STIFFNESS_PA_PER_M,
            }),
            ..Supports::default()
        };
        assert!(tray([0.0, 0.0, 1.0]).unable_to_hold(&g).is_none());
        // 20° from level with μ = 0.2 (11.3°): slides.
        let t = 20f64.to_radians();
        let steep = tray([t.sin(), 0.0, t.cos()]).unable_to_hold(&g);
        assert!(steep.is_some_and(|m| m.contains("slide")));
        assert!(tray([0.0, 0.0, -1.0]).unable_to_hold(&g).is_some());
    }
}
